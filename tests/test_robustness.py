"""Hostile but realistic input (docs/robustness.md): one line and exit code 2, or it works; nothing
written outside ``--out``; nothing stale left; a rerun with other settings refused."""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from asg.cli import main
from sumo_scenarios.lanes import Lane, LaneMap

from conftest import car, make_scene, rsu
from test_cli import assert_one_line_error, run

ROOT = Path(__file__).resolve().parent.parent


# ---- a small valid scene, written as yaml ---------------------------------------------------------
def _road() -> LaneMap:
    """A straight 2+2-lane road along x, 300 m long."""
    lanes = [Lane(f"e_{i}", np.array([[-150.0, -1.6 - 3.2 * i], [150.0, -1.6 - 3.2 * i]]), 3.2, 13.9) for i in range(2)]
    lanes += [Lane(f"w_{i}", np.array([[150.0, 1.6 + 3.2 * i], [-150.0, 1.6 + 3.2 * i]]), 3.2, 13.9) for i in range(2)]
    return LaneMap(lanes)


def _scene_dict(scene_id: str = "road_t0") -> dict:
    cars = [car(f"v{i}", -30.0 + 12.0 * i, -1.6 if i % 2 else -4.8) for i in range(6)]
    cars += [car(f"u{i}", -25.0 + 14.0 * i, 1.6, math.pi) for i in range(3)]
    scene = make_scene(_road(), [rsu("rsu0", 0.0, 9.0), *cars], ego="rsu0", collaborators=("v1", "u1"))
    d = scene.to_dict()
    d["scene_id"] = scene_id
    return d


def oracle_run(tmp_path: Path, n_scenes: int, *extra: str, out: str = "run") -> Path:
    """``asg generate`` in this process with the fake oracle detector on synthetic scenes s0, s1, ...
    (written to tmp_path/scenes); ``extra`` flags added. Returns the run folder tmp_path/out."""
    scenes = tmp_path / "scenes"
    for i in range(n_scenes):
        _write(scenes, _scene_dict(f"s{i}"))
    folder = tmp_path / out
    assert main(["generate", "--scenes", str(scenes), "--detector", "fakes:oracle_factory", "--count", str(n_scenes),
                 "--workers", "1", "--out", str(folder), *extra]) == 0
    return folder


def _write(folder: Path, d: dict, name: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / f"{name or d['scene_id']}.yaml"
    p.write_text(yaml.safe_dump(d))
    return p


GEN = ["--fusion", "none", "--search", "rs", "--acs", "random", "--budget", "2", "--seed", "1"]


def _generate(capsys, scenes: Path, out: Path, *extra: str):
    return run(capsys, "generate", "--scenes", str(scenes), "--out", str(out), *GEN, *extra)


def _files_outside(root: Path, allowed: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.is_file() and allowed not in p.parents and p.suffix != ".yaml"]


# ---- 1. numbers that crashed python-fcl ------------------------------------------------------------
def _agent(d, i):
    return d["agents"][i]


HOSTILE = {
    "x inf": lambda d: _agent(d, 3).update(x_m=math.inf),
    "x 1e308": lambda d: _agent(d, 3).update(x_m=1e308),
    "length 1e300": lambda d: _agent(d, 3).update(length_m=1e300),
    "ego y -inf": lambda d: _agent(d, 0).update(y_m=-math.inf),
    "every yaw NaN": lambda d: [a.update(yaw_rad=math.nan) for a in d["agents"]],
    "negative width": lambda d: _agent(d, 2).update(width_m=-1.0),
    "unknown kind": lambda d: _agent(d, 2).update(kind="tank"),
    "duplicate id": lambda d: _agent(d, 2).update(id="v0"),
    "one-point lane": lambda d: d["lanes"]["lanes"][0].update(centerline=[[0.0, 0.0]]),
    "one-point building": lambda d: d.update(buildings=[{"id": "b", "height_m": 5.0, "footprint": [[1.0, 1.0]]}]),
    "string as number": lambda d: _agent(d, 3).update(x_m="12 m"),
    "type SUMO refuses": lambda d: _agent(d, 3).update(type='a "b"'),
    "null id": lambda d: _agent(d, 3).update(id=None),
    "list-shaped scene": lambda d: d.clear(),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_scene_numbers_are_one_line(capsys, tmp_path, case):
    d = _scene_dict()
    HOSTILE[case](d)
    scenes = tmp_path / "scenes"
    p = _write(scenes, d if d else {"scene_id": "x"}, "bad")
    if case == "list-shaped scene":
        p.write_text("- 1\n- 2\n")
    out = tmp_path / "out"
    code, err = _generate(capsys, scenes, out)
    assert code == 2, err
    assert_one_line_error(err, "bad.yaml")
    assert not out.exists()
    code, err = run(capsys, "render", str(p), "--out", str(tmp_path / "x.png"))
    assert code == 2 and not (tmp_path / "x.png").exists()
    assert_one_line_error(err, "bad.yaml")


# ---- 2. ids that would write outside the folder -----------------------------------------------------
@pytest.mark.parametrize("where,value", [("scene_id", "../../escaped"), ("scene_id", "/tmp/abs"),
                                         ("ego", "../../x"), ("ego", ".hidden")])
def test_unsafe_ids_are_refused(capsys, tmp_path, where, value):
    d = _scene_dict()
    if where == "ego":
        _agent(d, 0)["id"] = value
        d["ego"] = value
    else:
        d["scene_id"] = value
    scenes = tmp_path / "in" / "scenes"
    p = _write(scenes, d, "unsafe")
    out = tmp_path / "in" / "out"
    code, err = _generate(capsys, scenes, out)
    assert code == 2
    assert_one_line_error(err, "not a safe name")
    code, err = run(capsys, "render", str(p), "--out", str(tmp_path / "in" / "x.png"), "--pcd-dir", str(tmp_path / "in" / "pcd"))
    assert code == 2
    assert_one_line_error(err, "not a safe name")
    assert not _files_outside(tmp_path, tmp_path / "in" / "out")


# ---- 3. resume that told the truth ---------------------------------------------------------------
@pytest.mark.slow
def test_a_rerun_with_other_settings_is_refused_and_force_starts_over(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    out = tmp_path / "out"
    code, err = _generate(capsys, scenes, out)
    assert code == 0, err
    first = (out / "summary.json").read_text()
    for other in (["--search", "ga"], ["--seed", "2"], ["--count", "3"], ["--fusion", "early"]):
        argv = ["generate", "--scenes", str(scenes), "--out", str(out), *GEN, *other]
        code, err = run(capsys, *argv)
        assert code == 2, other
        assert_one_line_error(err, "other settings", "--force")
    assert (out / "summary.json").read_text() == first  # untouched
    code, err = _generate(capsys, scenes, out, "--seed", "2", "--force")
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["seed"] == 2 and len(summary["scenes"]) == 1


@pytest.mark.slow
def test_a_run_resumed_after_the_shipped_weights_changed_is_refused(capsys, tmp_path):
    """run.json records the digest of the shipped weights the run loads: a folder made with other
    shipped weights (an earlier install) is refused, not finished with today's."""
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    out = tmp_path / "out"
    assert _generate(capsys, scenes, out)[0] == 0
    first = (out / "summary.json").read_text()
    record = json.loads((out / "run.json").read_text())
    record["shipped_weights_sha256"]["single"] = "0" * 64  # made with other shipped weights
    (out / "run.json").write_text(json.dumps(record))
    code, err = _generate(capsys, scenes, out)
    assert code == 2
    assert_one_line_error(err, "other settings", "shipped_weights_sha256.single", "--force")
    assert (out / "summary.json").read_text() == first


@pytest.mark.slow
def test_a_folder_written_before_a_setting_existed_resumes(capsys, tmp_path):
    """A run.json without a setting added since (its default reproduces the old behaviour) is the
    same settings; the same key with another value is not."""
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    out = tmp_path / "out"
    assert _generate(capsys, scenes, out)[0] == 0
    record = json.loads((out / "run.json").read_text())
    assert set(record["shipped_weights_sha256"]) == {"single"}  # the target's (ACS random: no AttFuse)
    del record["config"]["weights"], record["config"]["space"]["plausibility"], record["shipped_weights_sha256"]
    (out / "run.json").write_text(json.dumps(record))
    assert _generate(capsys, scenes, out)[0] == 0
    code, err = _generate(capsys, scenes, out, "--plausibility", "traffic")
    assert code == 2
    assert_one_line_error(err, "other settings", "plausibility")


def test_duplicate_scene_ids_are_refused(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("same"), "a")
    _write(scenes, _scene_dict("same"), "b")
    code, err = _generate(capsys, scenes, tmp_path / "out")
    assert code == 2
    assert_one_line_error(err, "'same' appears twice")


@pytest.mark.slow
def test_damaged_scene_folders_are_generated_again(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s1"))
    _write(scenes, _scene_dict("s2"))
    out = tmp_path / "out"
    assert _generate(capsys, scenes, out)[0] == 0
    before = json.loads((out / "summary.json").read_text())
    (out / "scenes" / "s1" / "result.json").write_text('{"scene_id": "s1", "ap_')  # truncated
    (out / "scenes" / "s2" / "detections.npz").unlink()
    code, err = _generate(capsys, scenes, out)
    assert code == 0, err
    after = json.loads((out / "summary.json").read_text())
    strip = lambda s: [{k: v for k, v in e.items() if k != "seconds"} for e in s["scenes"]]
    assert strip(after) == strip(before)  # regenerated to the same numbers


# ---- 4. output locations and values --------------------------------------------------------------
def test_output_location_problems_are_one_line_before_any_work(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    for out, needle in ((a_file, "is a file"), (a_file / "sub", "is a file")):
        code, err = _generate(capsys, scenes, out)
        assert code == 2, err
        assert_one_line_error(err, needle)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_output_is_one_line(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    code, err = _generate(capsys, scenes, ro / "out")
    assert code == 2
    assert_one_line_error(err, "writable")


@pytest.mark.parametrize("argv,needle", [
    (["generate", "--seed", "-5"], "--seed"),
    (["generate", "--count", "12345678901234567890"], "--count"),
    (["generate", "--count", "0"], "--count"),
    (["generate", "--budget", "nan"], "--budget"),
    (["simulate", "--town", "fiveleg", "--record-period", "nan", "--out", "OUT"], "--record-period"),
    (["simulate", "--town", "fiveleg", "--duration", "nan", "--out", "OUT"], "--duration"),
    (["simulate", "--town", "fiveleg", "--duration", "inf", "--out", "OUT"], "--duration"),
    (["evaluate", "--fusion", "none", "--limit", "-1"], "--limit"),
    (["evaluate", "--fusion", "none", "--limit", "0"], "--limit"),
    (["simulate", "--town", "../nets/fiveleg", "--out", "OUT"], "unknown town"),
    (["render", "SCENE", "--out", "x.png", "--collaborators", "-1"], "--collaborators"),
    # an empty value (a shell variable never set) would be the current folder or the default model
    (["simulate", "--town", "fiveleg", "--out", ""], "--out: an empty value"),
    (["generate", "--fusion", "", "--out", "OUT"], "--fusion: an empty value"),
    (["generate", "--detector=", "--out", "OUT"], "--detector: an empty value"),
    (["export", " ", "--format", "kitti", "--out", "OUT"], "source: an empty value"),
    (["evaluate", "--set", ""], "--set: an empty value"),
    # an option of another source or format is refused, not ignored
    (["simulate", "--town", "fiveleg", "--env", "merge-v0", "--out", "OUT"], "--env applies to --source highway-env"),
    (["simulate", "--source", "highway-env", "--step", "0.05", "--out", "OUT"], "--step applies to SUMO"),
    (["export", "normal-val", "--format", "kitti", "--net", "x.net.xml", "--out", "OUT"],
     "--net applies to the formats that read the scenes' SUMO net (openscenario, sumo)"),
])
def test_bad_values_are_one_line(capsys, tmp_path, argv, needle):
    argv = [str(tmp_path / "out") if a == "OUT" else str(tmp_path / "s.yaml") if a == "SCENE" else a for a in argv]
    code, err = run(capsys, *argv)
    assert code == 2
    assert_one_line_error(err, needle)
    assert not (tmp_path / "out").exists()


BAD_CONFIGS = {
    "acs_samples: -2\n": "acs_samples",
    "acs_tau: 0\n": "acs_tau",
    "comm_range_m: -1\n": "comm_range_m",
    "perturbed: -1\n": "perturbed",
    "sensing_agents: 0\n": "sensing_agents",
    "space: {dxy_m: 0}\n": "dxy_m",
    "space: {dyaw_deg: .nan}\n": "dyaw_deg",
    "space: {n_q: 0}\n": "n_q",
    "objective: {weights: {'0.3': 1.0, 'high': 2.0}}\n": "objective.weights",
    "objective: {weights: {'0.3': -1.0}}\n": "objective.weights",
    "- a\n- b\n": "expected a mapping",
    "budget: [1\n": "not valid YAML",
}


@pytest.mark.parametrize("text", sorted(BAD_CONFIGS))
def test_bad_generate_configs_are_one_line_naming_the_file(capsys, tmp_path, text):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    cfg = tmp_path / "mine.yaml"
    cfg.write_text(text)
    code, err = _generate(capsys, scenes, tmp_path / "out", "--config", str(cfg))
    assert code == 2
    assert_one_line_error(err, BAD_CONFIGS[text])
    assert "generate.yaml" not in err
    assert not (tmp_path / "out").exists()


def test_non_utf8_inputs_are_one_line(capsys, tmp_path):
    cfg = tmp_path / "latin1.yaml"
    cfg.write_bytes("budget: 5 # caf\xe9\n".encode("latin-1"))
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    code, err = _generate(capsys, scenes, tmp_path / "out", "--config", str(cfg))
    assert code == 2
    assert_one_line_error(err, "UTF-8")
    bad_scene = scenes / "z.yaml"
    bad_scene.write_bytes(b"scene_id: \xff\xfe\n")
    code, err = run(capsys, "render", str(bad_scene), "--out", str(tmp_path / "x.png"))
    assert code == 2
    assert_one_line_error(err, "UTF-8")


@pytest.mark.slow
def test_another_objective_weighting_is_used(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    cfg = tmp_path / "w.yaml"
    cfg.write_text("objective: {weights: {'0.6': 1.0}}\nspace: {dxy_m: 1.0, dyaw_deg: 10.0}\n")
    out = tmp_path / "out"
    code, err = _generate(capsys, scenes, out, "--config", str(cfg))
    assert code == 0, err
    (entry,) = json.loads((out / "summary.json").read_text())["scenes"]
    assert set(entry["ap_final"]) == {"0.3", "0.5", "0.6", "0.7"}
    assert entry["loss_final"] == pytest.approx(entry["ap_final"]["0.6"], abs=1e-6)
    rows = (out / "scenes" / entry["scene_id"] / "history.csv").read_text().splitlines()
    header = rows[0].split(",")
    for row in rows[1:]:  # moves in the configured bounds (1 m, 10 deg), not the paper's 2.5 m / 45 deg
        for name, value in zip(header, row.split(",")):
            if name.endswith(("_dx_m", "_dy_m")):
                assert abs(float(value)) <= 1.0 + 1e-9
            if name.endswith("_dyaw_deg"):
                assert abs(float(value)) <= 10.0 + 1e-9


@pytest.mark.slow
def test_the_summary_reads_each_scene_once_and_pools_as_from_scratch(tmp_path, monkeypatch):
    """The summary rewritten after every scene reads each scene's detections once (a 699-scene run
    re-read and re-matched every scene each time: 12 s a rewrite), and pools the same AP as a
    computation from the files."""
    from asg.generator import run_folder
    from asg.generator.stages import Stage

    reads = []
    real = run_folder.load_detections
    monkeypatch.setattr(run_folder, "load_detections", lambda out, sid: reads.append(sid) or real(out, sid))
    out = oracle_run(tmp_path, 3, "--budget", "4")
    assert sorted(reads) == ["s0", "s1", "s2"]
    agg = json.loads((out / "summary.json").read_text())["aggregate"]
    per_scene = [real(out, sid) for sid in ("s0", "s1", "s2")]
    for stage in Stage:
        fresh = run_folder.pooled_ap_by_method(per_scene, stage)
        assert {m: agg["by_method"][m][stage.ap_key] for m in fresh} == fresh


# ---- 5. a source smaller than --count ----------------------------------------------------------------
@pytest.mark.slow
def test_count_beyond_the_source_says_how_many(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    code, err = _generate(capsys, scenes, tmp_path / "out", "--count", "1000000")
    assert code == 0
    assert "holds 1 usable scenes (asked for 1000000)" in err


# ---- 6. leftovers and signals ------------------------------------------------------------------------
@pytest.mark.slow
def test_stale_partials_are_removed_on_rerun(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    out = tmp_path / "out"
    assert _generate(capsys, scenes, out)[0] == 0
    stale = [out / "scenes" / ".road_t0.abc123.tmp", out / ".summary.xyz.tmp.json", out / ".work"]
    for p in stale:
        p.mkdir() if not p.suffix == ".json" else p.write_text("{")
    assert _generate(capsys, scenes, out)[0] == 0
    assert not [p for p in stale if p.exists()]


@pytest.mark.slow
@pytest.mark.parametrize("interrupted_write", [1, 3], ids=["first-scene-summary", "final-summary"])
def test_ctrl_c_while_the_summary_is_written(capsys, tmp_path, monkeypatch, interrupted_write):
    """Ctrl-C while ``asg generate`` writes its summary (after a scene, or the final one): half the
    text written when it lands. Exit 130, no temporary file, summary.json absent or a whole earlier
    one; the rerun completes every scene."""
    from asg.generator import run_folder
    from sumo_scenarios.atomic import atomic_path

    scenes = tmp_path / "scenes"
    for i in range(2):
        _write(scenes, _scene_dict(f"s{i}"))
    out = tmp_path / "out"
    writes = []

    def write_then_interrupt(path, text):
        writes.append(path)
        if len(writes) != interrupted_write:
            return write_text_atomic(path, text)
        with atomic_path(path) as tmp:
            tmp.write_text(text[: len(text) // 2])
            raise KeyboardInterrupt

    write_text_atomic = run_folder.write_text_atomic
    monkeypatch.setattr(run_folder, "write_text_atomic", write_then_interrupt)
    code, err = _generate(capsys, scenes, out, "--workers", "1")
    assert code == 130 and "interrupted" in err and len(writes) == interrupted_write
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]
    summary = out / "summary.json"
    assert not summary.exists() or len(json.loads(summary.read_text())["scenes"]) == interrupted_write - 1
    monkeypatch.setattr(run_folder, "write_text_atomic", write_text_atomic)
    code, err = _generate(capsys, scenes, out, "--workers", "1")
    assert code == 0, err
    assert [e["scene_id"] for e in json.loads(summary.read_text())["scenes"]] == ["s0", "s1"]


def _wait_for(condition, what: str, proc: subprocess.Popen, limit_s: float = 300.0) -> None:
    """Poll ``condition()`` until true (a marker on disk, not a clock); fail if ``proc`` ended first."""
    deadline = time.time() + limit_s
    while not condition():
        assert proc.poll() is None, f"the run ended before {what}"
        assert time.time() < deadline, f"no {what} after {limit_s} s"
        time.sleep(0.05)


_SIGNAL_CASES = [pytest.param(moment, sig, "local", id=f"{sig.name}-{moment.replace(' ', '-')}")
                 for moment in ("workers starting", "first scene written", "last scene")
                 for sig in (signal.SIGTERM, signal.SIGINT)]
_SIGNAL_CASES += [pytest.param("workers starting", signal.SIGINT, "ray", id="ray-SIGINT-starting"),
                  pytest.param("first scene written", signal.SIGTERM, "ray", id="ray-SIGTERM-first-scene")]


@pytest.mark.slow
@pytest.mark.parametrize("moment, sig, executor", _SIGNAL_CASES)
def test_signal_mid_run_says_so_and_leaves_nothing(tmp_path, moment, sig, executor):
    """SIGTERM or Ctrl-C to a two-worker ``asg generate`` (local processes, or Ray actors on a local
    Ray instance, whose start-up and C++ waits take signals their own way): exit 143 / 130, no
    temporary file, no process left behind; the same command then resumes and completes (checked
    after the first scene and during the last: it costs the remaining scenes)."""
    psutil = pytest.importorskip("psutil")
    if executor == "ray":
        pytest.importorskip("ray")
    scenes = tmp_path / "scenes"
    # "last scene": four scenes, the signal once two are written, so the last two are in flight (with three,
    # the third could end within the moment it takes to signal, once seen under load)
    n_scenes = 4 if moment == "last scene" else 3
    for i in range(n_scenes):
        _write(scenes, _scene_dict(f"s{i}"))
    out, tmp = tmp_path / "out", tmp_path / "systemtmp"
    tmp.mkdir()
    # Ray keeps its session (sockets, logs) under the system's temporary folder: a pytest path there
    # would pass the 107-byte limit of a socket's name
    env = dict(os.environ, TMPDIR=str(tmp)) if executor == "local" else dict(os.environ)
    argv = [sys.executable, "-m", "asg", "generate", "--scenes", str(scenes), "--out", str(out),
            "--fusion", "none", "--search", "rs", "--acs", "random", "--budget", "150", "--workers", "2",
            "--executor", executor]
    # as a terminal's foreground job: Ctrl-C not ignored, even when these tests run in the background
    # of a non-interactive shell (whose jobs start with SIGINT ignored, which Python keeps)
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, env=env, text=True, cwd=ROOT,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    if moment == "workers starting":  # local: the pool's two workers; Ray: its node's first processes
        _wait_for(lambda: len(psutil.Process(proc.pid).children()) >= (2 if executor == "local" else 1),
                  "worker processes", proc)
    else:  # the first scene written, or two (the last two in flight)
        written = 1 if moment == "first scene written" else 2
        _wait_for(lambda: len(list((out / "scenes").glob("s*"))) >= written, f"{written} finished scenes", proc)
    family = psutil.Process(proc.pid).children(recursive=True)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    code, word = (143, "terminated") if sig == signal.SIGTERM else (130, "interrupted")
    assert proc.returncode == code, err
    assert word in err and "Traceback" not in err
    _, alive = psutil.wait_procs(family, timeout=10)
    assert not alive, alive  # workers and helpers end with their parent
    leftovers = [p for p in out.rglob("*") if p.name.startswith(".")]
    assert not leftovers, leftovers
    assert not list(tmp.iterdir())  # no folder in the system's temporary directory
    if (sig, moment) not in ((signal.SIGTERM, "first scene written"), (signal.SIGINT, "last scene")):
        return
    resumed = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert sorted(p.name for p in (out / "scenes").iterdir()) == [f"s{i}" for i in range(n_scenes)]


def _holds_int_and_term(pid: int) -> bool:
    """Does process ``pid`` block SIGINT and SIGTERM now (/proc/PID/status SigBlk): inside asg's
    start, past the interpreter's own (which no Python program can hold signals in)?"""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    blocked = int(next(l.split()[1] for l in status.splitlines() if l.startswith("SigBlk:")), 16)
    return all(blocked >> (int(s) - 1) & 1 for s in (signal.SIGINT, signal.SIGTERM))


_SLOW_START = [("bench paper", 0.0), ("bench paper", 1.0), ("bench paper", 2.0), ("bench paper", 2.5),
               ("bench paper", 3.0), ("bench paper", 5.0), ("dataset build challenging", 1.0),
               ("dataset build challenging", 2.0), ("dataset build challenging", 3.0), ("harden one worker", 1.0),
               ("harden one worker", 3.0), ("harden", 1.0), ("harden", 3.0)]


@pytest.mark.slow
@pytest.mark.parametrize("command, moment", [("generate", 0.0), ("generate", 0.3), ("generate", 1.0),
                                             ("generate", "workers starting"), ("dataset build", 0.0),
                                             ("dataset build", 2.0), ("dataset build", "first log"),
                                             ("harden", 0.0), ("harden", 2.0),
                                             *(pytest.param(*c, marks=pytest.mark.slow) for c in _SLOW_START)])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_to_the_group_while_it_starts_ends_it(tmp_path, command, moment, sig):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) or SIGTERM at the start of
    a two-worker ``asg generate``, ``asg dataset build`` or ``asg harden``: while the command imports (trimesh
    swallowed a KeyboardInterrupt there and the run went on to exit 0; ``moment`` seconds after
    asg's start holds the signals, or later when the imports are done), while its workers import,
    or (``dataset build``) once a worker has simulated a log: exit 130 / 143 within seconds (no
    summary written), one line, no traceback from any process of the group, none left, and no
    temporary folder (the simulated logs beside the set included)."""
    psutil = pytest.importorskip("psutil")
    scenes = tmp_path / "scenes"
    for i in range(2):
        _write(scenes, _scene_dict(f"s{i}"))
    out = tmp_path / "out"
    if command == "generate":
        argv = [sys.executable, "-m", "asg", "generate", "--scenes", str(scenes), "--out", str(out),
                "--fusion", "none", "--search", "rs", "--acs", "random", "--budget", "150", "--workers", "2"]
        env = dict(os.environ)
    elif command == "dataset build":  # a data set built from scratch: SUMO runs, then frames are rendered on the workers
        argv = [sys.executable, "-m", "asg", "dataset", "build", "heuristic", "--workers", "2"]
        env = dict(os.environ, ASG_DATA=str(out))
    elif command == "dataset build challenging":  # the normal set first, then the attack on it
        argv = [sys.executable, "-m", "asg", "dataset", "build", "challenging", "--fusion", "attfuse", "--split", "val",
                "--workers", "2"]
        env = dict(os.environ, ASG_DATA=str(out))
    elif command == "bench paper":  # its sets, then its runs
        argv = [sys.executable, "-m", "asg", "bench", "paper", "--scenes", "2", "--workers", "2", "--out", str(out / "bench")]
        env = dict(os.environ, ASG_DATA=str(out / "data"))
    else:  # a hardening run on an empty data root: it builds its pool and evaluation sets first
        workers = "1" if command == "harden one worker" else "2"
        argv = [sys.executable, "-m", "asg", "harden", "--fusion", "attfuse", "--rounds", "1", "--workers", workers,
                "--out", str(out / "harden")]
        env = dict(os.environ, ASG_DATA=str(out / "data"))

    def foreground():  # its own group, Ctrl-C not ignored (see the test above)
        os.setpgrp()
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=ROOT,
                            preexec_fn=foreground, env=env)
    if moment == "workers starting":
        _wait_for(lambda: len(psutil.Process(proc.pid).children()) >= 2, "worker processes", proc)
    elif moment == "first log":  # a worker has simulated a log (beside the set), the others run on
        _wait_for(lambda: any((out / ".work-heuristic").glob("*/*")), "a simulated log", proc)
    else:  # somewhere in asg's start (the interpreter's own start is before it); every moment must end the same way
        _wait_for(lambda: _holds_int_and_term(proc.pid), "asg's start", proc)
        time.sleep(moment)
    family = psutil.Process(proc.pid).children(recursive=True) if proc.poll() is None else []
    os.killpg(proc.pid, sig)
    sent = time.time()
    _, err = proc.communicate(timeout=60)
    code, word = (143, "terminated") if sig == signal.SIGTERM else (130, "interrupted")
    # 130 / 143, or ended by the signal itself after saying so (once in a loaded run, a SIGINT still
    # pending at the interpreter's exit): a shell reports both as 130 / 143
    assert proc.returncode in (code, -sig), err
    # it stopped, rather than finishing the run: promptly (a generous bound, for a loaded machine)
    assert time.time() - sent < 15.0 and not (out / "summary.json").exists()
    # the command's one line; nothing from a worker, also one whose interpreter was starting
    assert word in err and "Traceback" not in err and len([l for l in err.splitlines() if l.strip()]) == 1, err
    _, alive = psutil.wait_procs(family, timeout=10)
    assert not alive, alive
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]


_HARDEN_TINY = """harden:
  mix_with: [normal]
  eval_sets: [normal-val]
  scenes_per_round: 1
  pool: [normal]
  noisy: false
  reattack: false
  guard_set: null
  asg: {steps: 30, batch_size: 1, checkpoint_every: 1, fit_stage: false}
"""


@pytest.mark.slow
@pytest.mark.parametrize("moment, sig", [  # each phase and each signal in CI (slow), the other pairs exhaustive
    pytest.param("attack", signal.SIGINT, id="SIGINT-attack"),
    pytest.param("attack", signal.SIGTERM, id="SIGTERM-attack", marks=pytest.mark.exhaustive),
    pytest.param("fine-tuning", signal.SIGINT, id="SIGINT-fine-tuning", marks=pytest.mark.exhaustive),
    pytest.param("fine-tuning", signal.SIGTERM, id="SIGTERM-fine-tuning")])
def test_a_signal_to_a_hardening_run_past_its_start_ends_it_and_it_resumes(tmp_path, monkeypatch, moment, sig):
    """Ctrl-C (SIGINT to the group) or SIGTERM to a two-worker ``asg harden`` (the real AttFuse, on
    a tiny synthetic data root) while its round attacks on the workers, or while it fine-tunes
    (a checkpoint written): exit 130 / 143 within seconds, one line, no process of the group left,
    no temporary file; the same command then resumes and finishes the round (from the attack's
    finished scenes, or from the fine-tuning's checkpoint)."""
    psutil = pytest.importorskip("psutil")
    from asg.perception.targets import resolve_target
    from asg.workflows.challenging import build_challenging
    from test_tables import write_set

    root = tmp_path / "data"
    write_set(root, "normal", {"train": ["n0", "n1"], "val": ["n2"]})
    monkeypatch.setenv("ASG_DATA", str(root))
    build_challenging(resolve_target("attfuse"), "val", detector_factory="fakes:oracle_factory")  # round 0 evaluates on it
    config = tmp_path / "harden.yaml"
    config.write_text(_HARDEN_TINY)
    out = tmp_path / "harden"
    argv = [sys.executable, "-m", "asg", "harden", "--fusion", "attfuse", "--rounds", "1", "--workers", "2",
            "--config", str(config), "--out", str(out)]
    env = dict(os.environ, ASG_DATA=str(root))

    def foreground():  # its own group, Ctrl-C not ignored (see test_a_signal_to_the_group_while_it_starts_ends_it)
        os.setpgrp()
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=ROOT,
                            preexec_fn=foreground, env=env)
    if moment == "attack":  # round 1's attack folder claimed and the pool's workers up
        _wait_for(lambda: (out / "round-1" / "attack").is_dir() and len(psutil.Process(proc.pid).children()) >= 2,
                  "the round's attack on its workers", proc)
    else:  # the fine-tuning has written a checkpoint (one a step) and goes on
        _wait_for(lambda: (out / "round-1" / "last.pt").is_file(), "a fine-tuning checkpoint", proc)
    family = psutil.Process(proc.pid).children(recursive=True)
    os.killpg(proc.pid, sig)
    sent = time.time()
    _, err = proc.communicate(timeout=60)
    code, word = (143, "terminated") if sig == signal.SIGTERM else (130, "interrupted")
    assert proc.returncode in (code, -sig), err
    assert time.time() - sent < 15.0, err
    lines = [l for l in err.splitlines() if l.strip()]  # harden's log of its steps, then the one line
    assert word in lines[-1] and "Traceback" not in err and sum(l.startswith("asg:") for l in lines) == 1, err
    _, alive = psutil.wait_procs(family, timeout=10)
    assert not alive, alive
    assert not [p for p in out.rglob("*") if p.name.startswith(".") and p.name != ".complete"]  # no temporary file
    assert not (out / "round-1" / "weights.pt").exists()
    resumed = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=ROOT, timeout=900)
    assert resumed.returncode == 0, resumed.stderr
    if moment == "fine-tuning":
        assert "resumed fine-tuning at step" in resumed.stdout + resumed.stderr
    card = json.loads((out / "card.json").read_text())
    assert [r["round"] for r in card["rounds"]] == [0, 1] and (out / "round-1" / "weights.pt").is_file()


@pytest.mark.slow
def test_workers_end_when_their_parent_is_killed(tmp_path):
    """kill -9 of the parent: its workers end too (Linux's parent-death signal), none writes later."""
    psutil = pytest.importorskip("psutil")
    if not sys.platform.startswith("linux"):
        pytest.skip("the parent-death signal is Linux's")
    scenes = tmp_path / "scenes"
    for i in range(3):
        _write(scenes, _scene_dict(f"s{i}"))
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "asg", "generate", "--scenes", str(scenes), "--out", str(out),
            "--fusion", "none", "--search", "rs", "--acs", "random", "--budget", "300", "--workers", "2"]
    proc = subprocess.Popen(argv, stderr=subprocess.DEVNULL, stdout=subprocess.DEVNULL, cwd=ROOT)
    _wait_for(lambda: len(psutil.Process(proc.pid).children()) >= 2, "worker processes", proc)
    workers = psutil.Process(proc.pid).children()
    proc.kill()
    proc.wait(timeout=30)
    _, alive = psutil.wait_procs(workers, timeout=15)
    assert not alive, alive


def test_simulate_removes_stale_partials_beside_its_output(capsys, tmp_path):
    out = tmp_path / "log"
    stale = tmp_path / ".log.k9x.tmp"
    stale.mkdir()
    assert main(["simulate", "--town", "fiveleg", "--duration", "2", "--warmup", "5", "--out", str(out)]) == 0
    assert not stale.exists()


# ---- 7. messages that name the user's file -----------------------------------------------------------
def test_unusable_net_is_named(capsys, tmp_path):
    net = tmp_path / "tiny.net.xml"
    # one short dead-end lane: a readable net on which no trip fits
    net.write_text('<net version="1.20"><location netOffset="0,0" convBoundary="0,0,5,0"/>'
                   '<edge id="e" from="a" to="b"><lane id="e_0" index="0" speed="13.9" length="5" shape="0,0 5,0"/></edge>'
                   '<junction id="a" type="dead_end" x="0" y="0" incLanes="" intLanes="" shape="0,0"/>'
                   '<junction id="b" type="dead_end" x="5" y="0" incLanes="e_0" intLanes="" shape="5,0"/></net>')
    code, err = run(capsys, "simulate", "--net", str(net), "--duration", "5", "--out", str(tmp_path / "out"))
    assert code == 2
    assert "map.net.xml" not in err and "tiny.net.xml" in err


# ---- 8. byte-identical scene files ----------------------------------------------------------------
def test_scenes_from_a_town_record_no_temporary_path(tmp_path):
    from asg.generator.run import SceneSource, load_scenes

    scenes = load_scenes(SceneSource(town="fiveleg", duration_s=20.0), 2, 1, tmp_path / ".work")
    assert scenes and all(s.log is None for s in scenes)


# ---- 10. the independent plausibility check ----------------------------------------------------------
def test_recheck_catches_what_it_should():
    from asg.scene import Scene
    from asg.scene.recheck import recheck

    base = Scene.from_dict(_scene_dict())
    v2 = base.agent("v2")

    def moved_to(**kw):
        from dataclasses import replace

        return base.with_agents([replace(a, **kw) if a.agent_id == "v2" else a for a in base.agents])

    assert recheck(base, moved_to(x_m=v2.x_m + 1.0)).ok
    assert recheck(base, moved_to(x_m=base.agent("v3").x_m, y_m=base.agent("v3").y_m)).collisions == 1
    assert recheck(base, moved_to(y_m=-20.0)).off_road == 1
    assert recheck(base, moved_to(x_m=120.0)).out_of_range == 1


def test_recheck_accepts_every_member_of_q():
    """Both checks agree on plausible moves: every member of a feasible set passes the re-check."""
    from asg.scene import Scene
    from asg.scene.recheck import recheck
    from asg.search import FeasibleSet, SearchSpace, SpaceConfig

    scene = Scene.from_dict(_scene_dict())
    space = SearchSpace(scene, ("v2", "v3", "u0"), SpaceConfig(n_q=150))
    q = FeasibleSet(space, np.random.default_rng(3))
    for x in q.members:
        moved = space.moved_agents(x)
        assert recheck(scene, scene.with_agents([moved.get(a.agent_id, a) for a in scene.agents])).ok


# ---- 12. cooperation on for a user's own scenes -------------------------------------------------------
@pytest.mark.slow
def test_extract_picks_collaborators_and_evaluate_says_when_none(capsys, tmp_path, sumo_log):
    out = tmp_path / "scenes"
    assert main(["scenes", "extract", str(sumo_log), "--every", "40", "--out", str(out)]) == 0
    files = sorted(out.glob("*.yaml"))
    assert files and all(len(yaml.safe_load(f.read_text())["collaborators"]) == 2 for f in files)
    alone = tmp_path / "alone"
    assert main(["scenes", "extract", str(sumo_log), "--every", "40", "--collaborators", "0", "--out", str(alone)]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--fusion", "none", "--set", str(alone), "--limit", "1", "--json"]) == 0
    captured = capsys.readouterr()
    assert "name no collaborator" in captured.err
    assert json.loads(captured.out)["without_collaborators"] == 1


@pytest.mark.parametrize("digits", [400, 5000])
def test_integers_too_big_for_a_float_are_one_line(capsys, tmp_path, digits):
    """A coordinate written as an integer of hundreds (OverflowError in float()) or thousands of
    digits (beyond Python's integer-string limit, raised inside the YAML parser) is one line."""
    from test_cli import assert_one_line_error, run

    scenes = tmp_path / "scenes"
    path = _write(scenes, _scene_dict("s0"))
    text = path.read_text()
    first_x = text.index("x_m: ") + len("x_m: ")
    end = text.index("\n", first_x)
    path.write_text(text[:first_x] + "9" * digits + text[end:])
    code, err = run(capsys, "generate", "--scenes", str(scenes), "--out", str(tmp_path / "out"), *GEN)
    assert code == 2
    assert_one_line_error(err, "s0.yaml")


def test_an_id_ending_in_a_newline_is_not_safe():
    from sumo_scenarios.checks import safe_id
    from sumo_scenarios.errors import InputError

    assert safe_id("ok_1", "scene") == "ok_1"
    with pytest.raises(InputError, match="not a safe name"):
        safe_id("evil\n", "scene")


def test_a_rerun_notices_edited_scenes_and_takes_the_folder_however_spelled(capsys, tmp_path, monkeypatch):
    """The settings record holds the scenes' digest and the folder's absolute path: an edited scene
    is another input (refused without --force), ``./scenes`` is the same folder as its full path."""
    from test_cli import assert_one_line_error, run

    folder = oracle_run(tmp_path, 1)
    capsys.readouterr()
    monkeypatch.chdir(tmp_path)
    argv = ["generate", "--scenes", "./scenes", "--detector", "fakes:oracle_factory", "--count", "1",
            "--workers", "1", "--out", str(folder)]
    assert main(argv) == 0  # the same run: resumed, nothing to do
    capsys.readouterr()
    scene = tmp_path / "scenes" / "s0.yaml"
    scene.write_text(scene.read_text().replace("x_m: -30.0", "x_m: -31.0", 1))
    code, err = run(capsys, *argv)
    assert code == 2
    assert_one_line_error(err, "other settings")


@pytest.mark.slow
def test_openmp_threads_wait_passively_unless_the_user_says_otherwise():
    """asg sets OMP_WAIT_POLICY=PASSIVE with a short spin (GOMP_SPINCOUNT) before torch loads
    (long-spinning threads starve a shared machine, threads that sleep at once slow a frame:
    docs/results/speed.md), and keeps the values the user set."""
    import os
    import subprocess
    import sys

    import asg

    probe = ("import asg.cli, os, torch; "
             "print(os.environ['OMP_WAIT_POLICY'], os.environ.get('GOMP_SPINCOUNT', '-'))")
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}

    def seen(**user) -> str:
        return subprocess.run([sys.executable, "-c", probe], env={**env, **user}, capture_output=True,
                              text=True, check=True).stdout.strip()

    assert seen() == f"PASSIVE {asg.SHORT_SPIN_COUNT}"
    assert seen(GOMP_SPINCOUNT="0") == "PASSIVE 0"
    assert seen(OMP_WAIT_POLICY="ACTIVE") == "ACTIVE -"  # the user's policy: no spin count of asg's


@pytest.mark.parametrize("factory,needle", [
    ("fakes:nan_factory", "non-finite"),
    ("fakes:none_factory", "must return (boxes, scores)"),
    ("fakes:string_factory", "not real numbers"),
    ("fakes:shape_factory", "shape (K, 7)"),
    ("fakes:negative_size_factory", "sizes must be positive"),
    ("fakes:score_factory", "within [0, 1]"),
    ("fakes:million_factory", "1,000,000 boxes"),
    ("fakes:exit_in_detect_factory", "SystemExit"),
    ("fakes:hard_exit_in_detect_factory", "os._exit(0)"),
    ("fakes:hang_factory", "ran over"),
    ("fakes:swallowing_hang_factory", "ran over"),
    ("fakes:raising_factory", "no GPU found"),
    ("fakes:exit_factory", "SystemExit"),
    ("fakes:wrong_return_factory", "must return (target"),
    ("fakes:NOT_CALLABLE", "not a function"),
    ("bad_syntax_module:make", "SyntaxError"),
    ("bad_import_module:make", "ZeroDivisionError"),
])
def test_a_detector_from_outside_that_misbehaves_is_one_line(capsys, tmp_path, monkeypatch, factory, needle):
    """Every way a --detector factory can fail: one line naming it, exit 2, no run folder left;
    a detect() call that never returns is stopped at the time limit."""
    import asg.perception.plugins as plugins
    from asg.cli import main
    from test_cli import assert_one_line_error

    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "bad_syntax_module.py").write_text("def make(cfg)\n    return None\n")
    (tmp_path / "mods" / "bad_import_module.py").write_text("x = 1 / 0\n")
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    monkeypatch.setattr(plugins, "CALL_TIME_LIMIT_S", 1.0)
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s0"))
    out = tmp_path / "run"
    code = main(["generate", "--scenes", str(scenes), "--detector", factory, "--budget", "3", "--workers", "1",
                 "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert_one_line_error(err, needle)
    assert not out.exists()


def test_a_disk_that_fills_mid_write_is_one_line_naming_the_file(capsys, tmp_path, monkeypatch):
    """numpy's short write ("N requested and M written", no errno) and a full disk without a file
    name both end as one line naming the file being written; no partial file is left."""
    import errno

    import numpy as np
    from asg.cli import main
    from sumo_scenarios.atomic import atomic_path, write_text_atomic
    from test_cli import assert_one_line_error

    with pytest.raises(OSError) as exc:
        with atomic_path(tmp_path / "a.npy"):
            raise OSError("48416 requested and 47072 written")
    assert exc.value.errno == errno.ENOSPC and exc.value.filename == str(tmp_path / "a.npy")
    monkeypatch.setattr("pathlib.Path.write_text", lambda *a, **k: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device")))
    with pytest.raises(OSError) as exc:
        write_text_atomic(tmp_path / "b.json", "{}")
    assert exc.value.filename == str(tmp_path / "b.json")
    monkeypatch.undo()

    def short_write(file, arr, *a, **k):
        raise OSError("48416 requested and 47072 written")

    monkeypatch.setattr(np, "save", short_write)
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s0"))
    out = tmp_path / "run"
    code = main(["generate", "--scenes", str(scenes), "--detector", "fakes:oracle_factory", "--budget", "2",
                 "--workers", "1", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert_one_line_error(err, "No space left on device", ".npy")
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]


@pytest.mark.parametrize("edit, needle", [
    (lambda t: "bomb: &a [x, x]\nb2: &b [*a, *a]\n" + t.replace("\nlog: null", "\nlog: [*b, *b]"), "aliases"),
    (lambda t: t.replace("\ntown: ", "\ntown: other\ntown: "), "written twice"),
    (lambda t: t + "extra_key: 1\n", "unknown key 'extra_key'"),
    (lambda t: t.replace("\nlog: null", "\nlog: [1, 2]"), "'log' must be text")])
def test_a_hostile_scene_file_is_one_line(capsys, tmp_path, edit, needle):
    """Aliases (a bomb expands to gigabytes once used), a key written twice, a key no scene has, a log
    that is not text: refused in one line before anything runs."""
    scenes = tmp_path / "scenes"
    path = _write(scenes, _scene_dict("s0"))
    path.write_text(edit(path.read_text()))
    code, err = run(capsys, "generate", "--scenes", str(scenes), "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, needle)
    assert not list((tmp_path / "o").glob("scenes/*"))


@pytest.mark.parametrize("argv, words", [
    (["evaluate", "--fusion", "early", "--set", ""], "--set: an empty value"),
    (["evaluate", "--fusion", "early", "--set", " "], "--set: an empty value"),
    (["evaluate", "--fusion", "early", "--set", "normal\nval"], "unknown set 'normal\\nval'"),
    (["train", "--fusion", "early", "--init-from", ""], "--init-from: an empty value"),
])
def test_empty_and_multi_line_names_are_one_line(argv, words, capsys):
    """An empty --set or --init-from is not the flag left out (it read the current folder, or the
    model's own weights); a name with a newline is quoted, so the error stays one line."""
    from test_cli import assert_one_line_error, run

    code, err = run(capsys, *argv)
    assert code == 2
    assert_one_line_error(err, words)


def _damaged_set(tmp_path, how: str):
    """A data set folder (index.json + frames.jsonl.gz) damaged as ``how`` says."""
    import gzip
    import json

    folder = tmp_path / how
    folder.mkdir()
    (folder / "index.json").write_text(json.dumps({"name": how, "frames": 1, "splits": {"all": ["s0"]}}))
    frames = folder / "frames.jsonl.gz"
    if how == "garbage":
        frames.write_bytes(b"\x00not gzip at all" * 10)
    elif how == "truncated":
        frames.write_bytes(gzip.compress(b'{"scene_id": "s0", "agents": []}\n' * 100)[:40])
    elif how == "symlink":
        target = tmp_path / "elsewhere.gz"
        target.write_bytes(gzip.compress(b"{}\n"))
        frames.symlink_to(target)
    elif how == "one-huge-line":
        with gzip.open(frames, "wb", compresslevel=1) as fh:
            for _ in range(20):
                fh.write(b"x" * (1 << 20))
    elif how == "not-a-scene":
        frames.write_bytes(gzip.compress(b"[1, 2, 3]\n"))
    elif how == "bad-index":
        (folder / "index.json").write_text("{\"splits\": 3}")
        frames.write_bytes(gzip.compress(b"{}\n"))
    return folder


@pytest.mark.parametrize("how", ["garbage", "truncated", "symlink", "one-huge-line", "not-a-scene", "bad-index"])
@pytest.mark.parametrize("command", ["evaluate", "export"])
def test_a_damaged_data_set_is_one_line(how, command, capsys, tmp_path):
    from test_cli import assert_one_line_error, run

    folder = _damaged_set(tmp_path, how)
    argv = (["evaluate", "--fusion", "early", "--set", str(folder)] if command == "evaluate"
            else ["export", str(folder), "--format", "sumo", "--out", str(tmp_path / "out")])
    code, err = run(capsys, *argv)
    assert code == 2, err
    assert_one_line_error(err, "")


@pytest.mark.parametrize("ids, splits, says", [
    (["s0", "s1"], {"all": ["s0", "s1", "s9"]}, "split 'all' names 1 scenes that frames.jsonl.gz does not hold (e.g. 's9')"),
    (["s0", "s1"], {"all": ["s0", ["s1"]]}, "no splits of scene ids")])
def test_a_data_set_whose_frames_and_index_disagree_is_refused(tmp_path, ids, splits, says):
    """A split naming scenes the frames lack (a set silently smaller than its index says), or ids
    that are not text, is one line, not a quieter wrong number or a traceback."""
    import gzip
    import json

    from asg.datasets import iter_frames
    from sumo_scenarios.errors import InputError

    folder = tmp_path / "set"
    folder.mkdir()
    (folder / "index.json").write_text(json.dumps({"name": "set", "frames": len(ids), "splits": splits}))
    with gzip.open(folder / "frames.jsonl.gz", "wt", encoding="utf-8") as fh:
        fh.writelines(json.dumps(_scene_dict(i)) + "\n" for i in ids)
    with pytest.raises(InputError) as error:
        list(iter_frames(folder, "all"))
    assert says in str(error.value)


def test_a_data_set_may_repeat_an_id(tmp_path):
    """detector-train holds the same town, seed and time at two densities: two scenes of one id,
    both read; as a set of scenes (asg generate --scenes, evaluate, export) the second is ID-2,
    where a run would otherwise refuse the set or write both into one folder."""
    import gzip
    import json

    from asg.datasets import iter_frames, scenes_of

    folder = tmp_path / "set"
    folder.mkdir()
    (folder / "index.json").write_text(json.dumps({"name": "set", "frames": 3, "splits": {"all": ["s0", "s1", "s0"]}}))
    with gzip.open(folder / "frames.jsonl.gz", "wt", encoding="utf-8") as fh:
        fh.writelines(json.dumps(_scene_dict(i)) + "\n" for i in ("s0", "s1", "s0"))
    assert [s.scene_id for s in iter_frames(folder, "all")] == ["s0", "s1", "s0"]
    assert [s.scene_id for s in scenes_of(str(folder))] == ["s0", "s1", "s0-2"]


@pytest.mark.parametrize("factory, code, word", [("fakes:sigint_swallowed_factory", 130, "interrupted"),
                                                 ("fakes:sigterm_swallowed_factory", 143, "terminated")],
                         ids=["SIGINT", "SIGTERM"])
def test_a_signal_swallowed_by_code_it_interrupts_still_ends_the_run(capsys, tmp_path, factory, code, word):
    """A Ctrl-C or SIGTERM whose exception third-party code swallows (``except BaseException``, as
    trimesh's optional imports do) still ends the command with its exit code, before the next step."""
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s0"))
    out = tmp_path / "run"
    assert main(["generate", "--scenes", str(scenes), "--detector", factory, "--budget", "20", "--workers", "1",
                 "--out", str(out)]) == code
    err = capsys.readouterr().err
    assert word in err and "Traceback" not in err
    assert not list(out.rglob("final.yaml"))  # ended at once: no scene finished its search


_SIGNAL_IN_AN_AT_FORK_HOOK = """
import os, signal, sys
from asg import interrupts

def after_fork_in_parent():  # as logging's lock release is, when the signal lands inside it
    if sys.argv[1] == "signal":
        interrupts._on_signal(signal.SIGTERM, None)
    else:
        raise ValueError("a real fault")

with interrupts.handled():
    os.register_at_fork(after_in_parent=after_fork_in_parent)
    child = os.fork()
    if child == 0:
        os._exit(0)
    os.waitpid(child, 0)
    try:
        interrupts.raise_if_taken()
    except interrupts.Terminated:
        print("raised again")
"""


@pytest.mark.parametrize("what", ["signal", "fault"])
def test_a_signal_the_interpreter_swallows_in_a_fork_hook_prints_no_traceback(what):
    """A SIGTERM landing in an at-fork hook (CI caught one in logging's ``_releaseLock`` while
    ``asg harden`` forked its workers) is swallowed by the interpreter with an "Exception ignored"
    traceback: that print is dropped and the signal is raised again; any other exception swallowed
    there is still reported."""
    proc = subprocess.run([sys.executable, "-c", _SIGNAL_IN_AN_AT_FORK_HOOK, what], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    if what == "signal":
        assert proc.stdout.strip() == "raised again" and proc.stderr == "", proc.stderr
    else:
        assert proc.stdout == "" and "Exception ignored" in proc.stderr and "a real fault" in proc.stderr


@pytest.mark.slow
@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_detector_that_never_returns_and_swallows_every_exception_is_stopped(tmp_path, workers):
    """detect() loops forever inside ``except BaseException``: no raise can end it, so after the time
    limit and a few swallowed TimeoutErrors the process gives up, in one line, exit 2 (with two
    workers, the worker's line is said by the command)."""
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s0"))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "asg", "generate", "--scenes", str(scenes), "--detector",
                           "fakes:stuck_with_short_limit_factory", "--budget", "3", "--workers", workers,
                           "--out", str(tmp_path / "run")], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert_one_line_error(proc.stderr, "ran over 1 s")
    assert "catches every exception" in proc.stderr


@pytest.mark.parametrize("maker", ["open", "mkdir"])
def test_a_signal_as_the_temporary_file_is_made_leaves_nothing(tmp_path, monkeypatch, maker):
    """Ctrl-C (or asg's SIGTERM) the moment the temporary file or folder exists: the writer knows
    its name already and removes it (a SIGTERM to a Ray run once left ``.summary.*.tmp.json``
    behind, made a few statements before the writer's ``try``)."""
    from sumo_scenarios import atomic

    real = getattr(os, maker)

    def made_then_signalled(*args, **kwargs):
        made = real(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the handler runs here, whichever thread the kernel gave the signal to
        return made

    monkeypatch.setattr(os, maker, made_then_signalled)
    # Ctrl-C's own handler: a job started in the background of a shell (CI's) inherits SIGINT ignored
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            if maker == "open":
                atomic.write_text_atomic(tmp_path / "summary.json", "{}")
            else:
                with atomic.atomic_dir(tmp_path / "scene"):
                    pass
    finally:
        signal.signal(signal.SIGINT, previous)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_pipe_beside_a_users_weights_is_not_read(tmp_path):
    """The model card beside ``--weights NAME.pt`` (NAME.json) is read for the LiDAR it was trained
    for: a pipe there would block the read forever; it is skipped as no card."""
    import shutil

    from asg.perception.weights_io import weights_path
    from asg.training.cards import lidar_of_weights

    import threading

    weights = shutil.copy(weights_path("attfuse"), tmp_path / "mine.pt")
    os.mkfifo(tmp_path / "mine.json")
    found = []
    reader = threading.Thread(target=lambda: found.append(lidar_of_weights(weights)), daemon=True)
    reader.start()
    reader.join(30)  # a blocked read would hold the suite: the thread is left behind instead
    assert not reader.is_alive() and found == [None]


def test_an_empty_or_unmakeable_data_folder_is_the_default_or_one_line(capsys, monkeypatch):
    """``ASG_DATA=""`` (a variable set to nothing) is the default folder, not the current one; one
    that cannot be made is one line, not a traceback from the first data set built in it."""
    from asg.dataset_spec import data_root
    from sumo_scenarios.paths import runs_dir
    from test_cli import assert_one_line_error, run

    monkeypatch.setenv("ASG_DATA", "")
    assert data_root() == runs_dir() / "datasets"
    monkeypatch.setenv("ASG_DATA", "/proc/asg-data")
    code, err = run(capsys, "evaluate", "--fusion", "none", "--set", "normal-val", "--limit", "1")
    assert code == 2
    assert_one_line_error(err, "ASG_DATA=/proc/asg-data", "cannot be created")
