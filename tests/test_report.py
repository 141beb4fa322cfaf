"""``asg report``: one self-contained page that headless Chromium (Debian's chromium package)
opens with every inline image decoded; no network reference in it."""
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from asg.cli import main

from test_cli import assert_one_line_error, run
from test_robustness import oracle_run


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    raise AssertionError("Chromium is needed for this test: apt-get install chromium (make setup installs it)")


WINDOW = (1300, 4200)  # tall enough to hold both scenes' views in one screenshot


def _chromium_run(page, *args) -> subprocess.CompletedProcess:
    return subprocess.run([_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                           f"--window-size={WINDOW[0]},{WINDOW[1]}", "--virtual-time-budget=15000", *args,
                           page.as_uri()], capture_output=True, text=True, timeout=180)


@pytest.mark.slow
def test_report_renders_in_headless_chromium(capsys, tmp_path):
    """Every inline image decodes, and each 3D view draws: its WebGL canvas, found by the page's own
    script, holds drawn (non-background) pixels in a screenshot."""
    import numpy as np
    from PIL import Image

    out = oracle_run(tmp_path, 2, "--budget", "4")
    assert main(["report", str(out), "--scenes", "2"]) == 0
    page = out / "report.html"
    text = page.read_text()
    assert "s0" in text and "s1" in text and "after ACS" in text
    own = re.sub(r"<script>/\*\*\n\* plotly\.js.*?</script>", "", text, count=1, flags=re.S)
    assert len(own) < len(text) - 1_000_000  # plotly.js is inline (its own source names web pages)
    assert not re.search(r"(src|href)=['\"]https?:", own)  # self-contained
    dom = _chromium_run(page, "--dump-dom").stdout
    total = int(re.search(r'data-images="(\d+)"', dom).group(1))
    decoded = int(re.search(r'data-images-ok="(\d+)"', dom).group(1))
    assert total == decoded == 3  # the loss chart and one row of three views per scene
    rects = [tuple(map(int, r.split(","))) for r in re.search(r'data-views3d="([^"]*)"', dom).group(1).split(";")]
    assert len(rects) == 2 and all(w > 300 and h > 300 for _, _, w, h in rects)
    _chromium_run(page, f"--screenshot={tmp_path / 'shot.png'}")
    shot = np.asarray(Image.open(tmp_path / "shot.png").convert("RGB")).astype(int)
    for x, y, w, h in rects:
        assert y + h <= WINDOW[1], "the 3D view lies below the screenshot: raise WINDOW"
        canvas = shot[y:y + h, x:x + w]
        drawn = (np.abs(canvas - canvas[2, 2]).sum(axis=2) > 60).mean()  # differs from the corner's background
        assert drawn > 0.01, f"the 3D view at {(x, y, w, h)} is blank ({drawn:.4f} of its pixels drawn)"
    capsys.readouterr()


def test_report_of_nothing_is_one_line(capsys, tmp_path):
    code, err = run(capsys, "report", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, "no run folder")


def _tamper(path, edit):
    import json

    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


def test_a_run_folder_cannot_put_markup_or_paths_into_the_report(capsys, tmp_path):
    """Every value of summary.json is escaped (a config key, aggregate fields, a scene id with TeX
    or script), and a scene id that is a path is never followed."""
    out = oracle_run(tmp_path, 1, "--budget", "2")

    def evil(d):
        d["config"]["<script>alert(1)</script>"] = 1
        d["aggregate"]["scenes"] = "<script>alert(2)</script>"
        d["aggregate"]["seconds_per_scene_median"] = "<img src=x onerror=alert(3)>"
        d["scenes"].append(dict(d["scenes"][0], scene_id="../../../../etc"))
        d["scenes"].append(dict(d["scenes"][0], scene_id="$\\frac{1}{0$"))

    _tamper(out / "summary.json", evil)
    assert main(["report", str(out)]) == 0
    page = (out / "report.html").read_text()
    assert "<script>alert" not in page and "<img src=x" not in page
    assert "&lt;script&gt;alert(1)" in page and "../../../../etc" in page  # shown as text, not followed
    capsys.readouterr()


@pytest.mark.slow
def test_tampered_run_folders_are_one_line(capsys, tmp_path):
    import numpy as np

    cases = {
        "truncated": lambda o: (o / "summary.json").write_text((o / "summary.json").read_text()[:40]),
        "a list": lambda o: (o / "summary.json").write_text("[1, 2]"),
        "no aggregate": lambda o: _tamper(o / "summary.json", lambda d: d.pop("aggregate")),
        "AP null": lambda o: _tamper(o / "summary.json", lambda d: d["scenes"][0].update(ap_final=None)),
        "no detections": lambda o: (o / "scenes" / "s0" / "detections.npz").unlink(),
        "object array": lambda o: np.savez(o / "scenes" / "s0" / "detections.npz", x=np.array([{}], dtype=object)),
        "detections not a zip": lambda o: (o / "scenes" / "s0" / "detections.npz").write_bytes(b"PK\x03\x04garbage"),
        # 12 MB of zeros packed into a few kB: a larger one would fill the memory when read
        "detections a zip bomb": lambda o: np.savez_compressed(o / "scenes" / "s0" / "detections.npz",
                                                               final_boxes=np.zeros((220_000, 7)),
                                                               final_scores=np.zeros(1), final_gt=np.zeros((0, 7))),
        "history text": lambda o: (o / "scenes" / "s0" / "history.csv").write_text("step,loss\n1,abc\n"),
        "history without loss": lambda o: (o / "scenes" / "s0" / "history.csv").write_text("step\n1\n"),
        # never blocks on, follows or exhausts memory on a file where a json belongs
        "summary a FIFO": lambda o: _replace_with_fifo(o / "summary.json"),
        "a card a FIFO": lambda o: os.mkfifo(o / "card.json"),
        "a sub-run's summary a FIFO": lambda o: (shutil.copytree(o, o / "sub"), _replace_with_fifo(o / "sub" / "summary.json")),
        "summary a link to /dev/zero": lambda o: ((o / "summary.json").unlink(), (o / "summary.json").symlink_to("/dev/zero")),
        "zero.json a link to /dev/zero": lambda o: (o / "zero.json").symlink_to("/dev/zero"),
        "summary nested 200,000 deep": lambda o: (o / "summary.json").write_text("[" * 200_000 + "]" * 200_000),
    }
    template = oracle_run(tmp_path / "template", 1, "--budget", "2")
    capsys.readouterr()
    for name, edit in cases.items():
        out = tmp_path / name.replace(" ", "_") / "run"
        shutil.copytree(template, out)
        edit(out)
        code, err = run(capsys, "report", str(out))
        if code == 0:  # what is missing is simply not drawn
            assert not name.startswith("summary"), name  # the run's own summary is never skipped
            continue
        assert code == 2, name
        assert_one_line_error(err, str(out))


def _replace_with_fifo(path):
    path.unlink()
    os.mkfifo(path)


def test_the_final_view_marks_inserted_vehicles(cross_map):
    """A vehicle in the final scene and not in the initial one (the insert space) is drawn in a square."""
    import matplotlib.pyplot as plt
    import numpy as np

    from asg.report.page import _bev
    from asg.sensors import load_lidar_spec, simulate_frame
    from conftest import car, make_scene, rsu

    initial = make_scene(cross_map, [rsu("r", 8.0, 8.0), car("a", -10.0, -1.6)], collaborators=["a"])
    final = make_scene(cross_map, [rsu("r", 8.0, 8.0), car("a", -10.0, -1.6), car("new", 15.0, 1.6)],
                       collaborators=["a"])
    none = (np.zeros((0, 7)), np.zeros(0), np.zeros((0, 7)))
    squares = []
    for scene in (initial, final):
        fig, ax = plt.subplots()
        _bev(ax, scene, simulate_frame(scene, load_lidar_spec()), none, [], initial)
        squares.append(sum(line.get_marker() == "s" for line in ax.lines))
        plt.close(fig)
    assert squares == [0, 1]


@pytest.mark.slow
def test_links_huge_detections_and_bad_outputs_are_one_line(capsys, tmp_path):
    """A symbolic link anywhere in the folder (a table's .md linked to /etc/passwd put its lines in
    the page), a detections file of more boxes than asg writes (it ran for minutes), an --out under
    /proc or under a file: one line, exit 2, nothing read from elsewhere and nothing written."""
    import numpy as np

    out = oracle_run(tmp_path / "linked", 1, "--budget", "2")
    capsys.readouterr()
    (out / "evil.md").symlink_to("/etc/passwd")
    code, err = run(capsys, "report", str(out))
    assert code == 2
    assert_one_line_error(err, "symbolic link")
    assert not (out / "report.html").exists()

    out = oracle_run(tmp_path / "huge", 1, "--budget", "2")
    capsys.readouterr()
    npz = out / "scenes" / "s0" / "detections.npz"
    with np.load(npz) as z:
        arrays = dict(z)
    arrays["final_boxes"] = np.zeros((200_000, 7), np.float32)
    arrays["final_scores"] = np.full(200_000, 0.5, np.float32)
    np.savez(npz, **arrays)
    code, err = run(capsys, "report", str(out))
    assert code == 2
    assert_one_line_error(err, "boxes")

    out = oracle_run(tmp_path / "fine", 1, "--budget", "2")
    capsys.readouterr()
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for where in ("/proc/asg-report.html", str(a_file / "report.html")):
        code, err = run(capsys, "report", str(out), "--out", where)
        assert code == 2, where
        assert_one_line_error(err, "--out")


def test_report_never_writes_over_a_special_file_or_an_input_of_the_run(capsys, tmp_path):
    """--out onto a FIFO, a device node, a symbolic link or the run's own final.yaml / summary.json:
    one line, exit 2, the file untouched."""
    import os

    out = oracle_run(tmp_path / "run", 1, "--budget", "2")
    capsys.readouterr()
    fifo = tmp_path / "pipe.html"
    os.mkfifo(fifo)
    link = tmp_path / "link.html"
    link.symlink_to(tmp_path / "elsewhere.html")
    summary = out / "summary.json"
    before = summary.read_bytes()
    for where, words in ((fifo, "special file"), (Path("/dev/null"), "special file"), (link, "symbolic link"),
                         (summary, "file of the run")):
        code, err = run(capsys, "report", str(out), "--out", str(where))
        assert code == 2, where
        assert_one_line_error(err, words)
    assert fifo.is_fifo() and summary.read_bytes() == before and not (tmp_path / "elsewhere.html").exists()
    assert Path("/dev/null").is_char_device()


def test_a_detections_archive_that_unpacks_beyond_a_scene_is_not_unpacked(tmp_path):
    """A run folder is handed in: a detections.npz whose arrays unpack past what a scene holds (a
    few kB of zeros that would unpack to gigabytes) is refused from the archive's index, before
    any array is read."""
    import numpy as np

    from asg.generator.run_folder import MAX_DETECTION_ARRAY_BYTES, load_detections
    from sumo_scenarios.errors import InputError

    folder = tmp_path / "scenes" / "s0"
    folder.mkdir(parents=True)
    rows = MAX_DETECTION_ARRAY_BYTES // (7 * 8) + 1
    np.savez_compressed(folder / "detections.npz", final_boxes=np.zeros((rows, 7)), final_scores=np.zeros(1),
                        final_gt=np.zeros((0, 7)))
    assert (folder / "detections.npz").stat().st_size < 100_000
    with pytest.raises(InputError, match="final_boxes.npy: unpacks to .* regenerate the scene"):
        load_detections(tmp_path, "s0")
