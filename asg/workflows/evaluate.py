"""``asg evaluate``: AP of a fusion model on a data set or a folder of scenes (the scoring itself:
:mod:`asg.evaluation`)."""
from __future__ import annotations

import argparse

from ..cli_args import COUNT, executor_args, fusion_arg, weights_arg
from ..evaluation import GroundTruth, check_ground_truth, evaluate
from ..objective.pooled import PooledAP


# ``asg evaluate``: this workflow's command (asg.cli's COMMAND_MODULES)

def add_arguments(p: argparse.ArgumentParser) -> None:
    fusion_arg(p, "the model scored", required=True)
    p.add_argument("--set", default="normal", help="normal (train split), normal-val, normal-all, or a folder of scenes")
    p.add_argument("--limit", type=COUNT, default=None, help="only the first N scenes")
    weights_arg(p)
    p.add_argument("--ground-truth", choices=[g.value for g in GroundTruth], default=GroundTruth.ASG.value,
                   help="asg (default): every vehicle within 48 m of the ego; opencood: an OpenCOOD model scored as "
                        "OpenCOOD's own tools/inference.py scores it (its fixed range, the ego's own car where a "
                        "collaborator lists it; docs/opencood.md)")
    p.add_argument("--json", action="store_true", help="print JSON only")
    executor_args(p)


def run(args: argparse.Namespace) -> int:
    import contextlib
    import json

    from ..executors import build_executor
    from ..perception.targets import resolve_target
    from ..progress import console, print_result, progress_bar

    weights = None if args.weights is None else str(args.weights)
    target = resolve_target(args.fusion).check(weights)  # one line for an unknown fusion or a foreign file
    truth = check_ground_truth(GroundTruth(args.ground_truth), target)
    # without --workers or --executor: this process on every thread; else workers of one thread
    spread = args.workers is not None or args.executor != "local"
    with progress_bar() as bar, (build_executor(args.executor, args.workers or 1, threads=1, address=args.address)
                                 if spread else contextlib.nullcontext()) as executor:
        task = bar.add_task(f"evaluating {args.fusion}", total=args.limit)
        result = evaluate(target, args.set, args.limit, lambda n: bar.update(task, completed=n),
                          weights_file=weights, executor=executor, truth=truth)
    if note := target.evaluation_note():
        console.print(f"[yellow]note: {note}")
    if result["without_collaborators"]:
        console.print(f"[yellow]note: {result['without_collaborators']} of {result['frames']} scenes name no "
                      "collaborator, so cooperation is off there (every model scores as single-agent); "
                      "extract scenes with 'asg scenes extract --collaborators K'")
    if args.json:
        print(json.dumps({**PooledAP.from_result(result).to_json(), "frames": result["frames"],
                          "without_collaborators": result["without_collaborators"], "ground_truth": truth.value}))
    else:
        pooled = PooledAP.from_result(result)
        print_result(f"asg evaluate --fusion {args.fusion} --set {args.set} --ground-truth {truth.value}",
                     {**{f"AP@{k}": round(v, 4) for k, v in pooled.ap.items()},
                      **{f"AP@{k} per frame (paper)": round(v, 4) for k, v in pooled.ap_per_frame.items()},
                      "frames": result["frames"]}, False)
    return 0
