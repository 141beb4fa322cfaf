"""Each benchmark's defaults, read by its function (asg.benchmarks.NAME) and by its command's
parser (asg.commands.bench_NAME), which is built without importing torch: one source for both."""
from __future__ import annotations

#: ``asg bench simulate``: the town, simulated minutes (0.1 s steps) and timed runs
SIMULATE_TOWN = "grid_small"
SIMULATE_MINUTES = 10.0
SIMULATE_REPEATS = 3
#: ``asg bench lidar``: timed renders of each way
LIDAR_REPEATS = 15
#: ``asg bench detect``: normal frames (3 sensing agents) and rounds over them
DETECT_FRAMES = 10
DETECT_REPEATS = 3
#: ``asg bench generate``: normal scenes attacked
GENERATE_SCENES = 5
#: ``asg bench train``: steps timed after the warm-up ones
TRAIN_STEPS = 12
#: ``asg bench scale``: scenes of the generator benchmark each way runs
SCALE_SCENES = 8
