"""Ship the size sequence's wide AttFuse as ``--fusion attfuse-wide``: copy DIR/wide/attfuse.pt to
asg/perception/weights/attfuse-wide.pt and write its card from the sequence's (every chunk and the
branch fit as they ran), with what the package reads: its settings file
(configs/detectors/pointpillars-wide.yaml, whose settings must be the ones the sequence trained
with) and the wide single-agent weights it started from, named by their path in this repository
and their digest (the package ships no wide single network). Then validated on normal-val as
``asg train`` validates a chunk (the card's ``validation``).

    .venv/bin/python docs/experiments/ship_wide.py docs/experiments/size-sequence
"""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from asg.generator.run import file_digest
from asg.perception import check_weights_file
from asg.perception.fusion import card_settings_of, detector_config_of
from asg.perception.weights_io import WEIGHTS_DIR
from asg.training.cards import card_validation

sys.path.insert(0, str(Path(__file__).parent))
from size_sequence import SIZES  # noqa: E402  (this folder's)

NAME = "attfuse-wide"


def main(out: Path) -> None:
    cfg = detector_config_of(NAME)
    if cfg != SIZES["wide"]:
        raise SystemExit("configs/detectors/pointpillars-wide.yaml differs from the sequence's wide settings; "
                         "ship weights trained with the entry's settings")
    source = out / "wide" / "attfuse.pt"
    card = json.loads((out / "wide" / "attfuse.json").read_text())
    if card["chunks"][-1].get("part") != "branches":
        print("note: the sequence's last step was not the branch fit; shipping the weights as they are")
    check_weights_file(NAME, source)  # the weights load into the entry's network
    single = out / "wide" / "single.pt"
    card.update({"weights": f"{NAME}.pt", "fusion": [NAME],
                 "init_from": {**card["init_from"], "weights": str(single), "sha256": file_digest(single)},
                 **card_settings_of(NAME, cfg)})
    card.pop("validation", None)
    shutil.copyfile(source, WEIGHTS_DIR / f"{NAME}.pt")
    (WEIGHTS_DIR / f"{NAME}.json").write_text(json.dumps(card, indent=1))
    print(f"shipped {source} as {NAME} ({file_digest(source)[:16]})")
    card_validation(NAME, weights_dir=WEIGHTS_DIR)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(Path(sys.argv[1]))
