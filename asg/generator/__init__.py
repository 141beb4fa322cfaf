"""The generator: a run of the attack over many scenes into a run folder.

Its parts, lowest layer first: ``config`` (GenerateConfig, configs/generate.yaml and the named
protocols), ``pipeline`` (one scene: ACS, then APS, scored), ``run_folder`` (what a run folder
holds: results, summary, detections, the before/after table), ``run`` (open a run folder for a
source of scenes and run them on an executor: :func:`asg.generator.run.open_run`) and
``command`` (``asg generate``). Import the part you need; this package imports none of them.
"""
