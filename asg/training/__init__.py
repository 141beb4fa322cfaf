"""Training the detectors: settings (config), the loop, checkpoints, the branch and point-stage fits,
and model cards; ``asg train`` is :mod:`.command`. Each module has its own layer (tests/test_layers.py).
"""
