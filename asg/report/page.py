"""``asg report RUN_DIR``: one self-contained HTML page (images inline as PNG data, plotly.js
inline for the 3D views: no network).

RUN_DIR is an ``asg generate`` run folder, or any folder holding such run folders (the output of
``asg bench paper``: its configuration runs, and its tables ``TABLE.json`` when present). The page
holds, per run: the configuration, the before/after AP table (pooled and per scene), plausibility
(collisions, off the drivable area, out of range, as re-checked when written), the best loss so far
against the evaluation count, and bird's-eye views of the scenes that lost the most AP@0.7 at each
stage (normal, after ACS, final): the lanes, every sensing agent's LiDAR points coloured by agent
(rendered again from the stage's scene), the ego and its links to the collaborators, the ground
truth and the detections in distinct colours, and each moved vehicle's displacement from where it
was; below each scene's row, an interactive 3D view of its final stage (the fused cloud with
ground truth and detections); then the paper's tables beside ours; for an ``asg harden`` or ``asg
finetune`` folder, the table a round (or before / after) and the training curves
(asg.report.training). Written atomically to ``RUN_DIR/report.html`` unless told otherwise.
"""
from __future__ import annotations

import base64
import csv
import html
import io
import itertools
import json
import os
import zipfile
from pathlib import Path
from typing import Iterator

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sumo_scenarios.atomic import write_text_atomic  # noqa: E402
from sumo_scenarios.checks import is_safe_id  # noqa: E402
from sumo_scenarios.errors import InputError  # noqa: E402

from ..objective import ap_text  # noqa: E402
from ..objective.ap import Yardstick  # noqa: E402
from ..scene import footprint_xy, load_scene  # noqa: E402
from ..io.figures import points_above_ground  # noqa: E402
from ..io.json_file import read_json  # noqa: E402
from ..generator.run_folder import aggregate_ap, load_detections, read_summary, stage_scene_path  # noqa: E402
from ..schemas import CURRENT, SchemaFile  # noqa: E402
from ..generator.stages import Stage  # noqa: E402
from .training import training_folders, training_section  # noqa: E402
from .view3d import plotly_script, scene_view_html  # noqa: E402

STAGES = ((Stage.NORMAL, "normal"), (Stage.AFTER_ACS, "after ACS"), (Stage.FINAL, "final"))
#: colours: ground truth, detections, moved vehicles
GT_COLOUR, DET_COLOUR, MOVED_COLOUR = "#1a9850", "#d73027", "#4575b4"
#: each sensing agent's points and marker (none red or green: those are the boxes')
AGENT_COLOURS = ("tab:blue", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:cyan")
EXTENT_M = 50.0


def run_folders(root: Path) -> list[Path]:
    """``root`` if it is a run folder, else its sub-folders that are (sorted)."""
    if (root / "summary.json").is_file():
        return [root]
    return sorted(p.parent for p in root.glob("*/summary.json"))


def _refuse_links(root: Path) -> None:
    """One InputError if anything under ``root`` is a symbolic link: asg writes none, and the report
    must read only what the folder holds (a table linked to /etc/passwd put its lines in the page)."""
    for folder, dirs, files in os.walk(root, followlinks=False):
        for name in (*dirs, *files):
            if os.path.islink(os.path.join(folder, name)):
                raise InputError(f"{os.path.join(folder, name)}: a symbolic link inside the folder; the report reads "
                                 "only files the folder holds: copy the file in or remove the link")


def _output_file(out: Path, root: Path) -> Path:
    """``out`` if an HTML file can be written there, else one InputError (a folder or a file in the
    way, /proc, no permission, a device node, FIFO or socket, a symbolic link, or a file of the run
    itself other than its report.html: a special file or an input is never an output)."""
    import stat

    from sumo_scenarios.checks import output_dir

    if out.is_symlink():
        raise InputError(f"--out {out} is a symbolic link; give the HTML file's own path")
    if out.is_dir():
        raise InputError(f"--out {out} is a folder; give an HTML file name")
    if out.exists() and not stat.S_ISREG(out.stat().st_mode):
        raise InputError(f"--out {out} is a special file (a device, FIFO or socket); give an HTML file name")
    try:
        inside_run = out.resolve().is_relative_to(root.resolve())
    except OSError:
        inside_run = False
    if inside_run and out.exists() and out.name != "report.html":
        raise InputError(f"--out {out} is a file of the run folder {root}; give a new HTML file name")
    output_dir(out.parent)
    return out


def write_report(root: Path, out: Path | None = None, scenes_shown: int = 6) -> Path:
    root = Path(root)
    _refuse_links(root)
    out = _output_file(Path(out), root) if out is not None else root / "report.html"
    runs = run_folders(root)
    tables = sorted(p for p in root.glob("*.json") if _is_table(p))
    trainings = training_folders(root)
    if not runs and not tables and not trainings:
        raise InputError(f"{root}: no run folder (summary.json), table (TABLE.json) or training run (asg harden, "
                         "asg finetune) to report; give a folder written by 'asg generate', 'asg bench paper', "
                         "'asg harden' or 'asg finetune'")
    view_ids = itertools.count()  # the 3D views' div ids, unique in the page
    parts = [f"<h1>asg report: {html.escape(str(root))}</h1>"]
    parts += [_guarded(_run_section, r, "summary.json", scenes_shown, view_ids) for r in runs]
    parts += [_guarded(_table_section, p, p.name) for p in tables]
    parts += [_guarded(training_section, f, "the training card", _img, _html_table) for f in trainings]
    body = "\n".join(parts)
    head = plotly_script() if "class=view3d" in body else ""
    try:
        write_text_atomic(out, _PAGE.format(head=head, body=body))
    except OSError as exc:
        raise InputError(f"--out {out}: cannot be written ({exc.strerror}); give a writable place") from None
    except InputError as exc:  # the place itself (sumo_scenarios.atomic): named as the flag that gave it
        raise InputError(f"--out {exc}") from None
    return out


def _guarded(section, path: Path, what: str, *args) -> str:
    """``section(path, *args)``; a folder or file someone edited (a key missing, a string for a
    number, a list for a mapping, a broken detections file) is one InputError naming it."""
    try:
        return section(path, *args)
    except InputError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise InputError(f"{path}: {what} (or a file it names) is not what asg wrote ({type(exc).__name__}: "
                         f"{str(exc)[:80]}); regenerate it") from None


def _text(value) -> str:
    """Any value read from a run folder, as HTML text (the report never trusts a file's contents)."""
    return html.escape(str(value))


def _is_table(path: Path) -> bool:
    try:
        data = read_json(path)
    except InputError:
        return False
    return isinstance(data, dict) and {"table", "rows", "command"} <= set(data)


def _run_section(run: Path, scenes_shown: int, view_ids: Iterator[int]) -> str:
    summary, version = read_summary(run / "summary.json")
    cfg, agg, entries = summary["config"], summary["aggregate"], summary["scenes"]
    older = (f"<p class=note>summary.json of schema {version} (written by an earlier asg), read in today's "
             f"shape, schema {CURRENT[SchemaFile.SUMMARY]}.</p>" if version < CURRENT[SchemaFile.SUMMARY] else "")
    rows = [["pooled", *(ap_text(aggregate_ap(agg, stage)) for stage in Stage), "", ""]]
    per_frame = agg.get("by_method", {}).get(Yardstick.PER_FRAME) if isinstance(agg.get("by_method"), dict) else None
    if isinstance(per_frame, dict):  # the paper's yardstick: no sort across frames (docs/generate.md)
        rows.append(["pooled per frame (paper)", *(ap_text(aggregate_ap(agg, s, Yardstick.PER_FRAME)) for s in Stage), "", ""])
    for e in entries:
        p = e.get("plausibility", {})
        rows.append([e["scene_id"], *(ap_text(e[stage.ap_key]) for stage in Stage),
                     str(len(e.get("moved", []))),
                     f"{p.get('collisions', '-')} / {p.get('off_road', '-')} / {p.get('out_of_range', '-')}"])
    implausible = sum(any(v for v in e.get("plausibility", {}).values()) for e in entries)
    config = ", ".join(f"{_text(k)}: {_text(json.dumps(v))}" for k, v in cfg.items() if k not in ("objective", "space"))
    hardest = sorted((e for e in entries if is_safe_id(str(e["scene_id"]))), key=_ap_lost, reverse=True)
    views = "".join(_scene_views(run, e, next(view_ids)) for e in hardest[:scenes_shown])
    return (f"<section><h2>{html.escape(run.name)}</h2>{older}<p class=config>{config}</p>"
            f"<p>{_text(agg['scenes'])} scenes, median {_text(agg['seconds_per_scene_median'])} s a scene; "
            f"plausibility: {len(entries) - implausible} of {len(entries)} scenes with no collision, nothing off "
            f"the drivable area, nothing out of range.</p>"
            + _html_table(["scene", "normal AP@0.3/0.5/0.7 (%)", "after ACS", "final", "moved",
                           "collisions / off road / out of range"], rows)
            + f"<h3>Best loss so far against evaluations</h3>{_img(_loss_chart(run, entries))}"
            f"<h3>Bird's-eye views (the {min(scenes_shown, len(entries))} scenes that lost the most AP@0.7; "
            f"ego frame, metres)</h3>"
            f"<p><span style='color:{GT_COLOUR}'>&#9632; ground truth</span> "
            f"<span style='color:{DET_COLOUR}'>&#9632; detections</span> "
            f"<span style='color:{MOVED_COLOUR}'>&#9675;&rarr; moved vehicles and their displacement, "
            f"&#9633; inserted vehicles</span> "
            f"&#9650; the ego (black) and its collaborators, linked; dots: each agent's LiDAR points (its colour, "
            f"ground returns left out); grey lines: lane centres</p>{views}</section>")


def _ap_lost(entry: dict) -> float:
    """AP@0.7 the attack took from the scene (normal minus final); 0 if unreadable."""
    try:
        return float(entry[Stage.NORMAL.ap_key]["0.7"]) - float(entry[Stage.FINAL.ap_key]["0.7"])
    except (KeyError, TypeError, ValueError):
        return 0.0


def _scene_views(run: Path, entry: dict, index: int) -> str:
    """The scene's row of bird's-eye views (normal, after ACS, final) and the 3D view of its final
    stage (a ``<div>`` with id ``view3d-INDEX``)."""
    from ..sensors import load_lidar_spec, simulate_frame

    from ..perception.plugins import MAX_BOXES

    folder = run / "scenes" / entry["scene_id"]
    dets = load_detections(run, entry["scene_id"])
    if any(len(a) > MAX_BOXES for d in dets.values() for a in d):  # asg writes at most that many a frame
        raise InputError(f"{folder / 'detections.npz'}: more than {MAX_BOXES:,} boxes in a frame, which asg never "
                         "writes; regenerate the scene")
    fig, axes = plt.subplots(1, 3, figsize=(13.5, 4.8), dpi=80)
    normal_file = stage_scene_path(folder, Stage.NORMAL)
    normal = load_scene(normal_file) if normal_file.is_file() else None
    view3d = ""
    for ax, (key, label) in zip(axes, STAGES):
        scene_file = stage_scene_path(folder, key)
        if key in dets and scene_file.is_file():
            ap = entry[key.ap_key]
            scene = load_scene(scene_file)
            frame = simulate_frame(scene, load_lidar_spec())
            _bev(ax, scene, frame, dets[key], entry.get("moved", []) if key == Stage.FINAL else [],
                 normal if key == Stage.FINAL else None)
            ax.set_title(f"{label}: AP@0.7 {100 * ap['0.7']:.1f}", fontsize=10)
            if key == Stage.FINAL:
                view3d = scene_view_html(frame, dets[key][0], f"view3d-{index}", AGENT_COLOURS, GT_COLOUR, DET_COLOUR)
        else:
            ax.set_axis_off()
    fig.suptitle(entry["scene_id"], fontsize=10, parse_math=False)  # an id is text, never TeX
    fig.tight_layout()
    caption = (f"<figcaption>{_text(entry['scene_id'])}, final stage in 3D: the fused cloud (each agent's points "
               "in its colour, ground left out), ground truth and detections; drag to turn, scroll to zoom"
               "</figcaption>") if view3d else ""
    return f"<figure>{_img(fig)}</figure>" + (f"<figure class=view3d>{view3d}{caption}</figure>" if view3d else "")


def _bev(ax, scene, frame, detections: tuple, moved: list[str], normal=None) -> None:
    """Lanes, buildings, every sensing agent's LiDAR points (``frame``, rendered from ``scene``),
    the links, ground truth (green), detections (red, dashed) and the sensing agents, all in the
    ego's frame (the frame the detections are in); moved vehicles circled, with an arrow from where
    they stood in ``normal`` (the normal stage's scene); vehicles not in it (inserted) in a square."""
    boxes, scores, gt = detections
    ego = scene.ego
    c, s = np.cos(ego.yaw_rad), np.sin(ego.yaw_rad)
    to_ego = lambda xy: np.stack([c * (xy[:, 0] - ego.x_m) + s * (xy[:, 1] - ego.y_m),
                                  -s * (xy[:, 0] - ego.x_m) + c * (xy[:, 1] - ego.y_m)], axis=1)
    at = lambda aid, sc=scene: to_ego(np.array([[sc.agent(aid).x_m, sc.agent(aid).y_m]]))[0]
    for lane in scene.lane_map.lanes:
        xy = to_ego(np.asarray(lane.centerline_xy))
        ax.plot(xy[:, 0], xy[:, 1], color="0.75", lw=0.5, zorder=0)
    for b in scene.buildings:
        xy = to_ego(np.asarray(b.footprint_xy))
        ax.fill(xy[:, 0], xy[:, 1], color="0.88", zorder=0)
    for k, (_, pts, _) in enumerate(points_above_ground(frame)):
        ax.scatter(pts[:, 0], pts[:, 1], s=0.15, color=AGENT_COLOURS[k % len(AGENT_COLOURS)], zorder=1,
                   rasterized=True)
    for aid in scene.collaborators:
        ax.plot(*np.stack([at(scene.ego_id), at(aid)]).T, color="0.3", lw=0.8, ls=":", zorder=4)
    for box in gt:
        _outline(ax, box, GT_COLOUR, "-")
    for box, score in zip(boxes, scores):
        _outline(ax, box, DET_COLOUR, "--")
    for aid in moved:
        if any(a.agent_id == aid for a in scene.agents):
            p = at(aid)
            ax.add_patch(plt.Circle(p, 3.2, fill=False, color=MOVED_COLOUR, lw=1.5, zorder=4))
            if normal is not None and any(a.agent_id == aid for a in normal.agents):
                q = at(aid, normal)
                ax.annotate("", xy=p, xytext=q, arrowprops={"arrowstyle": "->", "color": MOVED_COLOUR, "lw": 1.2},
                            zorder=4)
    if normal is not None:  # vehicles the search inserted (the insert space): a square around each
        before = {a.agent_id for a in normal.agents}
        for a in scene.vehicles:
            if a.agent_id not in before:
                ax.plot(*at(a.agent_id), marker="s", ms=14, mfc="none", mec=MOVED_COLOUR, mew=1.5, zorder=4)
    for k, aid in enumerate(frame.sensing_ids):
        ax.plot(*at(aid), marker="^", color="k" if aid == scene.ego_id else AGENT_COLOURS[k % len(AGENT_COLOURS)],
                mec="k", markersize=8, zorder=5)
    ax.set_xlim(-EXTENT_M, EXTENT_M)
    ax.set_ylim(-EXTENT_M, EXTENT_M)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)


def _outline(ax, box: np.ndarray, colour: str, style: str) -> None:
    fp = footprint_xy(box[0], box[1], box[6], box[3], box[4])
    loop = np.vstack([fp, fp[:1]])
    ax.plot(loop[:, 0], loop[:, 1], color=colour, ls=style, lw=1.1, zorder=3)


def _loss_chart(run: Path, entries: list[dict]):
    fig, ax = plt.subplots(figsize=(7, 3.2), dpi=80)
    curves = []
    for e in entries:
        path = run / "scenes" / str(e["scene_id"]) / "history.csv"
        if not is_safe_id(str(e["scene_id"])) or not path.is_file():  # an id is a name, never a path out
            continue
        losses = [float(r["loss"]) for r in csv.DictReader(io.StringIO(path.read_text()))]
        if losses:
            best = np.minimum.accumulate(losses)
            curves.append(best)
            ax.plot(np.arange(1, len(best) + 1), best, color="0.75", lw=0.7)
    if curves:
        n = min(len(c) for c in curves)
        ax.plot(np.arange(1, n + 1), np.median([c[:n] for c in curves], axis=0), color=DET_COLOUR, lw=2,
                label="median over scenes")
        ax.legend(fontsize=8)
    ax.set_xlabel("evaluation")
    ax.set_ylabel("best loss so far")
    fig.tight_layout()
    return fig


def _table_section(path: Path) -> str:
    data = read_json(path, "the table")
    md = path.with_suffix(".md")
    body = _markdown_table_html(md.read_text()) if md.is_file() else ""
    return (f"<section><h2>Table {_text(data['table'])}</h2><p><code>{_text(data['command'])}</code>: "
            f"{_text(data['scenes'])} scenes, {_text(data.get('seconds'))} s, commit {_text(data.get('commit'))}</p>{body}</section>")


def _markdown_table_html(text: str) -> str:
    """The markdown tables of a TABLE.md as HTML (pipes to cells), other lines as paragraphs."""
    out, rows = [], []
    for line in text.splitlines() + [""]:
        if line.startswith("|"):
            if not set(line) <= set("|-: "):
                rows.append([c.strip().replace("**", "") for c in line.strip("|").split("|")])
            continue
        if rows:
            out.append(_html_table(rows[0], rows[1:]))
            rows = []
        if line.strip():
            out.append(f"<p>{html.escape(line)}</p>")
    return "".join(out)


def _html_table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _img(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return f"<img alt='chart' src='data:image/png;base64,{base64.b64encode(buf.getvalue()).decode('ascii')}'>"


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>asg report</title>
{head}
<style>
body {{ font-family: sans-serif; margin: 1.5em; color: #222; }}
table {{ border-collapse: collapse; margin: 0.6em 0; font-size: 0.85em; }}
td, th {{ border: 1px solid #bbb; padding: 2px 7px; text-align: right; }}
th {{ background: #eee; }} td:first-child {{ text-align: left; }}
img {{ max-width: 100%; }} figure.view3d {{ max-width: 1080px; border: 1px solid #ddd; }} .config {{ font-size: 0.8em; color: #555; }}
section {{ border-top: 2px solid #ccc; margin-top: 1.2em; }}
</style></head>
<body>
{body}
<script>
// for automated checks: how many inline images decoded (data-images-ok) of how many (data-images)
window.addEventListener("load", function () {{
  var imgs = Array.prototype.slice.call(document.images);
  document.body.setAttribute("data-images", imgs.length);
  document.body.setAttribute("data-images-ok", imgs.filter(function (i) {{ return i.complete && i.naturalWidth > 0; }}).length);
  // the 3D views: where each one's WebGL canvas lies on the page (x, y, width, height in CSS pixels)
  var rects = Array.prototype.slice.call(document.querySelectorAll(".view3d .js-plotly-plot")).map(function (d) {{
    var c = d.querySelector("canvas"); if (!c) {{ return "none"; }}
    var r = c.getBoundingClientRect();
    return [r.left + window.scrollX, r.top + window.scrollY, r.width, r.height].map(Math.round).join(",");
  }});
  document.body.setAttribute("data-views3d", rects.join(";"));
}});
</script>
</body></html>
"""
