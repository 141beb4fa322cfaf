"""Workflows: what runs the generator and the detectors many times to answer a question (hardening
a detector, its controls, the noisy-link evaluation). They sit above the generator and the stages
(scene, sensors, perception, objective, search) and import from them, never the other way round."""

#: at most this many rounds in one ``asg harden`` run (the CLI checks it before importing the workflow)
MAX_ROUNDS = 50
