"""Workflows: what runs the generator and the detectors many times to answer a question (hardening
a detector, its controls, the noisy-link evaluation). They sit above the generator and the stages
(scene, sensors, perception, objective, search) and import from them, never the other way round."""
