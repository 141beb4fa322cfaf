"""``asg report``: one self-contained HTML page of a run folder (``page``), with the training
curves of fine-tuning and hardening runs (``training``) and the 3D views of scenes (``view3d``)."""
