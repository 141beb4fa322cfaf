"""Bad input: exit code 2, one line on stderr naming the problem and the fix, no traceback, no partial output."""
from pathlib import Path

import pytest

from asg.cli import main
from sumo_scenarios.paths import nets_dir


def run(capsys, *argv):
    """(exit code, stderr) of ``asg ARGV``, whether argparse or the command refused it."""
    try:
        code = main(list(argv))
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.err


def assert_one_line_error(err: str, *needles: str):
    lines = [l for l in err.splitlines() if l.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("asg: error:") and "Traceback" not in err
    for n in needles:
        assert n in lines[0], lines[0]


@pytest.fixture
def out(tmp_path) -> Path:
    return tmp_path / "out"


def assert_nothing_written(out: Path):
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")], list(out.parent.iterdir())


def test_missing_net(capsys, out):
    code, err = run(capsys, "simulate", "--net", "/nonexistent/x.net.xml", "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "not found")
    assert_nothing_written(out)


def test_truncated_net(capsys, tmp_path, out):
    net = tmp_path / "trunc.net.xml"
    text = (nets_dir() / "fiveleg.net.xml").read_text()
    net.write_text(text[: len(text) // 2])
    code, err = run(capsys, "simulate", "--net", str(net), "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "not a readable SUMO net")
    assert_nothing_written(out)


def test_non_xml_net(capsys, tmp_path, out):
    net = tmp_path / "junk.net.xml"
    net.write_bytes(b"\x00\x01 definitely not xml")
    code, err = run(capsys, "simulate", "--net", str(net), "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "junk.net.xml")


def test_laneless_net(capsys, tmp_path, out):
    net = tmp_path / "empty.net.xml"
    net.write_text('<net version="1.20"><location netOffset="0,0" convBoundary="0,0,1,1"/></net>')
    code, err = run(capsys, "simulate", "--net", str(net), "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "no lanes")
    assert_nothing_written(out)


def test_unknown_town(capsys, out):
    code, err = run(capsys, "simulate", "--town", "atlantis", "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "unknown town 'atlantis'", "grid_small")


def test_negative_duration(capsys, out):
    code, err = run(capsys, "simulate", "--town", "grid_small", "--duration", "-5", "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "--duration must be positive")
    assert_nothing_written(out)


def test_unknown_yaml_key(capsys, tmp_path):
    cfg = tmp_path / "towns.yaml"
    cfg.write_text("towns: []\nbuildingz: {}\n")
    code, err = run(capsys, "towns", "build", "--config", str(cfg), "--out", str(tmp_path / "nets"))
    assert code == 2
    assert_one_line_error(err, "unknown key 'buildingz'")


def test_bad_flag_is_one_line(capsys):
    code, err = run_exit(capsys, "simulate", "--town", "grid_small", "--density", "insane", "--out", "x")
    assert code == 2
    assert_one_line_error(err, "--density")


def run_exit(capsys, *argv):
    with pytest.raises(SystemExit) as exc:
        main(list(argv))
    return exc.value.code, capsys.readouterr().err


def test_scene_file_missing_key_via_log(capsys, tmp_path):
    code, err = run(capsys, "scenes", "extract", str(tmp_path), "--out", str(tmp_path / "s"))
    assert code == 2
    assert_one_line_error(err, "not a traffic-log folder")


#: a log's meta.yaml spoiled (what is replaced, by what) -> what the one line says
BAD_META = {
    ("- id: rsu0", "- id: ../../../escaped"): "rsus[0]: id '../../../escaped' is not a safe name",
    ("town: grid_small", "town: ../up"): "town: id '../up' is not a safe name",
    ("map_file: map.net.xml", "map_file: ../../map.net.xml"): "is not in the log folder",
    ("  length_m: 4.6\n", "  length_m: -4.6\n"): "vehicle_types[0] length_m: -4.6 is out of range",
    ("  height_m: 1.48\n", ""): "vehicle_types[0] height_m: expected a number",
    ("  height_m: 4.5\n", "  height_m: .nan\n"): "height_m: nan is not a finite number",
}


@pytest.mark.parametrize("spoil", sorted(BAD_META))
def test_a_spoiled_log_folder_is_one_line_and_writes_nothing(spoil, capsys, tmp_path, sumo_log):
    """A log folder is handed in: an id in its meta.yaml names scene files (an RSU's '../..' wrote
    a scene outside --out), its files stay in it, its sizes are ones a scene can hold."""
    import shutil

    log = shutil.copytree(sumo_log, tmp_path / "log")
    meta = (log / "meta.yaml").read_text()
    old, new = spoil
    assert old in meta
    (log / "meta.yaml").write_text(meta.replace(old, new, 1))
    code, err = run(capsys, "scenes", "extract", str(log), "--every", "40", "--out", str(tmp_path / "a" / "b" / "s"))
    assert code == 2
    assert_one_line_error(err, BAD_META[spoil])
    assert not (tmp_path / "a").exists() and not (tmp_path / "escaped.yaml").exists()


@pytest.mark.parametrize("lanes", ['{"lanes": [1]}', '[1, 2]', '{"lanes": {"a": 1}}'])
def test_a_malformed_lane_file_is_one_line(lanes, capsys, tmp_path, sumo_log):
    """A highway-env log's lanes.json.gz of the wrong structure: one line naming it."""
    import gzip
    import shutil

    log = shutil.copytree(sumo_log, tmp_path / "log")
    meta = (log / "meta.yaml").read_text()
    (log / "meta.yaml").write_text(meta.replace("map_file: map.net.xml", "map_file: lanes.json.gz"))
    (log / "lanes.json.gz").write_bytes(gzip.compress(lanes.encode()))
    code, err = run(capsys, "scenes", "extract", str(log), "--out", str(tmp_path / "s"))
    assert code == 2
    assert_one_line_error(err, "lanes.json.gz: lane file unreadable")


def test_a_scene_folder_of_other_settings_is_refused_and_force_replaces_it(capsys, tmp_path, sumo_log):
    """Extracting into a folder of scenes made with other settings would mix two sets silently:
    refused in one line, nothing changed; the same settings again write the same files; --force
    replaces the folder's scenes. A folder of scene files with no record is refused too."""
    out = tmp_path / "scenes"
    extract = ["scenes", "extract", str(sumo_log), "--out", str(out)]
    assert main([*extract, "--every", "40"]) == 0
    first = {p.name: p.read_bytes() for p in out.glob("*.yaml")}
    assert main([*extract, "--every", "40"]) == 0
    assert {p.name: p.read_bytes() for p in out.glob("*.yaml")} == first
    capsys.readouterr()
    code, err = run(capsys, *extract, "--every", "20")
    assert code == 2
    assert_one_line_error(err, "other settings (every: 40 -> 20)", "--force")
    assert {p.name: p.read_bytes() for p in out.glob("*.yaml")} == first
    assert main([*extract, "--every", "20", "--collaborators", "0", "--force"]) == 0
    second = {p.name for p in out.glob("*.yaml")}
    assert len(second) > len(first) and all("collaborators: []" in (out / n).read_text() for n in second)
    (out / "run.json").unlink()
    capsys.readouterr()
    code, err = run(capsys, *extract, "--every", "20", "--collaborators", "0")
    assert code == 2
    assert_one_line_error(err, "recorded no settings")


def test_towns_list_json(capsys):
    import json

    assert main(["towns", "list", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) >= 6 and {"name", "area_km2", "lanes_max", "junctions", "buildings"} <= set(rows[0])


def test_simulate_and_extract_end_to_end(capsys, tmp_path):
    log = tmp_path / "log"
    assert main(["simulate", "--town", "fiveleg", "--duration", "10", "--warmup", "30", "--out", str(log)]) == 0
    assert main(["scenes", "extract", str(log), "--every", "5", "--out", str(tmp_path / "scenes")]) == 0
    assert len(list((tmp_path / "scenes").glob("*.yaml"))) == 5


def test_a_log_folder_of_other_settings_is_refused_and_force_replaces_only_the_log(capsys, tmp_path):
    log = tmp_path / "log"
    short = ["--town", "fiveleg", "--duration", "2", "--warmup", "30", "--out", str(log)]
    assert main(["simulate", *short]) == 0
    (log / "notes.txt").write_text("mine")
    names = sorted(p.name for p in log.iterdir())
    assert main(["simulate", *short]) == 0  # the same settings: the log again (SUMO dates its header)
    assert sorted(p.name for p in log.iterdir()) == names
    before = {p.name: p.read_bytes() for p in log.iterdir()}
    capsys.readouterr()
    code, err = run(capsys, "simulate", *short, "--seed", "2")
    assert code == 2
    assert_one_line_error(err, "other settings", "seed", "--force")
    assert {p.name: p.read_bytes() for p in log.iterdir()} == before  # nothing touched
    code, err = run(capsys, "simulate", "--source", "highway-env", "--env", "merge-v0", "--duration", "2",
                    "--out", str(log), "--force")
    assert code == 0, err
    assert not (log / "map.net.xml").exists() and (log / "lanes.json.gz").is_file()  # no file of the old log
    assert (log / "notes.txt").read_text() == "mine"  # nor of anyone else's
    (log / "run.json").unlink()  # a log that recorded no settings (written before they were recorded)
    code, err = run(capsys, "simulate", "--source", "highway-env", "--env", "merge-v0", "--duration", "2",
                    "--out", str(log))
    assert code == 2
    assert_one_line_error(err, "recorded no settings")


@pytest.mark.parametrize("where, needle", [("afile", "is a file where a folder is to be written"),
                                           ("afile/log", "a part of the path is a file"),
                                           ("/proc/asg-log", "no folder can be made there")])
def test_a_log_folder_where_none_can_be_made_is_one_line_before_simulating(capsys, tmp_path, where, needle):
    (tmp_path / "afile").write_text("mine")
    code, err = run(capsys, "simulate", "--town", "fiveleg", "--duration", "2", "--warmup", "1",
                    "--out", where if where.startswith("/") else str(tmp_path / where))
    assert code == 2
    assert_one_line_error(err, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"] and (tmp_path / "afile").read_text() == "mine"


def _one_scene(tmp_path, capsys) -> Path:
    log = tmp_path / "log"
    assert main(["simulate", "--town", "fiveleg", "--duration", "2", "--warmup", "30", "--out", str(log)]) == 0
    assert main(["scenes", "extract", str(log), "--every", "4", "--out", str(tmp_path / "scenes")]) == 0
    capsys.readouterr()
    return sorted((tmp_path / "scenes").glob("*.yaml"))[0]


def test_a_render_where_no_file_can_be_made_is_one_line_and_writes_nothing(capsys, tmp_path):
    scene = _one_scene(tmp_path, capsys)
    out = tmp_path / "out"
    out.mkdir()
    (out / "afile").write_text("mine")
    (out / "adir").mkdir()
    for argv, needle in ((["--out", str(out / "adir")], "is a folder where a file is to be written"),
                         (["--out", str(out / "afile" / "x.png")], "a part of the path is a file"),
                         (["--out", "/proc/asg-frame.png"], "no file can be made there"),
                         (["--out", str(out / "x.png"), "--pcd-dir", str(out / "afile")], "--pcd-dir")):
        code, err = run(capsys, "render", str(scene), *argv)
        assert code == 2, argv
        assert_one_line_error(err, needle)
        assert sorted(p.name for p in out.iterdir()) == ["adir", "afile"] and not any((out / "adir").iterdir())


def test_render_writes_picture_and_clouds(capsys, tmp_path):
    scene = _one_scene(tmp_path, capsys)
    out = tmp_path / "frame.png"
    assert main(["render", str(scene), "--out", str(out), "--pcd-dir", str(tmp_path / "pcd")]) == 0
    assert out.read_bytes()[:4] == b"\x89PNG"
    assert len(list((tmp_path / "pcd").glob("*.pcd"))) == 3 and len(list((tmp_path / "pcd").glob("*.npy"))) == 3


def test_render_bad_inputs(capsys, tmp_path):
    import yaml

    scene = _one_scene(tmp_path, capsys)
    data = yaml.safe_load(scene.read_text())
    # a scene missing a key
    broken = tmp_path / "broken.yaml"
    broken.write_text(yaml.safe_dump({k: v for k, v in data.items() if k != "agents"}))
    code, err = run(capsys, "render", str(broken), "--out", str(tmp_path / "x.png"))
    assert code == 2
    assert_one_line_error(err, "missing key 'agents'")
    # an empty scene: the ego alone
    empty = tmp_path / "empty.yaml"
    data_empty = dict(data, agents=[a for a in data["agents"] if a["id"] == data["ego"]], buildings=[], collaborators=[])
    empty.write_text(yaml.safe_dump(data_empty))
    code, err = run(capsys, "render", str(empty), "--out", str(tmp_path / "x.png"))
    assert code == 2
    assert_one_line_error(err, "empty scene")
    # a sensor with zero channels, one with a negative range
    for bad, needle in (("channels: 0", "channels: 0 is out of range"), ("range_m: -5.0", "range_m: -5 is out of range")):
        spec = tmp_path / "bad_lidar.yaml"
        spec.write_text(f"name: bad\n{bad}\n")
        code, err = run(capsys, "render", str(scene), "--lidar", str(spec), "--out", str(tmp_path / "x.png"))
        assert code == 2
        assert_one_line_error(err, needle)
    assert not (tmp_path / "x.png").exists()


@pytest.mark.slow
def test_generate_writes_the_run_folder_and_resumes(capsys, tmp_path):
    import json

    scene = _one_scene(tmp_path, capsys)
    scenes_dir = scene.parent
    out = tmp_path / "gen"
    argv = ["generate", "--scenes", str(scenes_dir), "--fusion", "none", "--search", "rs", "--acs", "random",
            "--count", "1", "--budget", "3", "--seed", "1", "--out", str(out)]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    (entry,) = summary["scenes"]
    folder = out / "scenes" / entry["scene_id"]
    for name in ("normal.yaml", "after_acs.yaml", "final.yaml", "history.csv", "normal.png", "after_acs.png",
                 "final.png", "detections.npz", "result.json"):
        assert (folder / name).is_file(), name
    assert len(list((folder / "clouds").glob("*.pcd"))) == 3
    history = (folder / "history.csv").read_text().splitlines()
    assert history[0].startswith("step") and len(history) == 1 + 3
    for key in ("ap_normal", "ap_after_acs", "ap_final"):
        assert set(entry[key]) == {"0.3", "0.5", "0.7"} and all(0 <= v <= 1 for v in entry[key].values())
    assert entry["plausibility"] == {"collisions": 0, "off_road": 0, "out_of_range": 0}
    assert entry["evaluations"] == 1 + 3 + 3 and len(entry["perturbed"]) <= 3
    agg = summary["aggregate"]
    assert agg["scenes"] == 1 and agg["wall_s"] > 0
    for key in ("ap_normal", "ap_after_acs", "ap_final"):  # one key per stage: a scene's and the pooled AP
        assert agg[key] == pytest.approx(entry[key], abs=1e-6)  # one scene: pooled = its own AP
        # both yardsticks are kept; on one frame they agree
        assert agg["by_method"]["global"][key] == agg[key]
        assert agg["by_method"]["per-frame"][key] == pytest.approx(entry[key], abs=1e-6)
    assert "per frame" in capsys.readouterr().out  # the pooled row of the paper's yardstick
    # the same command again: the finished scene is kept as it is, the wall time carried over
    before = (folder / "result.json").read_text()
    assert main(argv) == 0
    assert (folder / "result.json").read_text() == before
    assert json.loads((out / "summary.json").read_text())["aggregate"]["wall_s"] >= agg["wall_s"]


def test_train_validate_only_updates_the_card_without_training(capsys, monkeypatch):
    import asg.training.command as train_mod

    calls = []
    monkeypatch.setattr(train_mod, "card_validation",
                        lambda name, log, weights_dir: calls.append(name) or {"weights": f"{name}.pt"})
    monkeypatch.setattr(train_mod, "seed_run_folder", lambda run_dir, *names: None)
    monkeypatch.setattr(train_mod, "train", lambda *a, **k: pytest.fail("--validate-only must not train"))
    assert main(["train", "--fusion", "late", "--validate-only"]) == 0
    assert calls == ["single"]  # late shares the single-agent weights
    assert "updated the model card of single.pt" in capsys.readouterr().err
    code, err = run(capsys, "train", "--fusion", "single", "--validate-only")
    assert code == 2
    assert_one_line_error(err, "unknown fusion 'single'")
    code, err = run(capsys, "train", "--fusion", "early", "--validate-only", "--init-from", "single")
    assert code == 2
    assert_one_line_error(err, "cannot be combined with --init-from")


def test_bench_paper_bad_workers(capsys, out):
    code, err = run(capsys, "bench", "paper", "--workers", "0", "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "--workers")
    assert_nothing_written(out)


def test_bench_paper_refuses_a_folder_of_other_scenes(capsys, out):
    (out / "scenes-5").mkdir(parents=True)
    code, err = run(capsys, "bench", "paper", "--scenes", "4", "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "other scenes (scenes-5)")
    old = out.parent / "old-bench"  # written before the benchmark stored its scene pick
    (old / "attention-bo" / "scenes").mkdir(parents=True)
    code, err = run(capsys, "bench", "paper", "--scenes", "4", "--out", str(old))
    assert code == 2
    assert_one_line_error(err, "other scenes (a run without its scene folder)")


def test_a_new_workflow_is_one_module_and_one_registry_line(capsys, tmp_path, monkeypatch):
    """A workflow module declares its own subcommand (add_arguments, run); one line in
    COMMAND_MODULES makes it a command, with its arguments, one-line errors and exit codes."""
    import asg.cli as cli

    (tmp_path / "hello_workflow.py").write_text(
        "from asg.cli_args import COUNT\n"
        "def add_arguments(p):\n"
        "    p.add_argument('--times', type=COUNT, default=1)\n"
        "def run(args):\n"
        "    print('hello ' * args.times)\n"
        "    return 0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(cli, "COMMAND_MODULES", (*cli.COMMAND_MODULES, ("hello", "hello_workflow", "say hello")))
    assert main(["hello", "--times", "2"]) == 0
    assert capsys.readouterr().out.strip() == "hello hello"
    with pytest.raises(SystemExit) as exc:
        main(["hello", "--times", "0"])
    assert exc.value.code == 2 and "out of range" in capsys.readouterr().err
    assert "say hello" in cli.build_parser().format_help()


@pytest.mark.slow
def test_help_and_other_commands_do_not_import_the_workflows():
    """``asg --help`` and a non-workflow command build the parser without importing a workflow
    module (each pulls in torch and the data sets: seconds)."""
    import subprocess
    import sys

    probe = ("import sys; from asg.cli import build_parser; "
             "build_parser(['--help']); build_parser(['towns', 'list']); "
             "print(sorted(m for m in sys.modules if m.startswith('asg.workflows.'))); "
             "build_parser(['harden', '--help']); print('asg.workflows.harden' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[:2] == ["[]", "True"]


def test_an_unknown_fusion_is_refused_before_anything_runs(capsys, tmp_path, monkeypatch):
    """generate refused an unknown --fusion only inside its worker, after simulating the town's traffic."""
    import sumo_scenarios.simulate as simulate

    monkeypatch.setattr(simulate, "simulate_sumo", lambda *a, **k: pytest.fail("traffic simulated before the refusal"))
    code, err = run(capsys, "generate", "--town", "fiveleg", "--fusion", "nope", "--count", "1", "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, "unknown fusion 'nope'")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["generate", "evaluate", "train", "finetune", "harden", "dataset build", "bench paper"])
def test_every_fusion_option_lists_every_installed_detector(command, capsys, monkeypatch):
    from asg.perception.targets import detector_names

    monkeypatch.setenv("COLUMNS", "1000")  # argparse breaks lines at hyphens (attfuse-\nwide) at a terminal's width
    with pytest.raises(SystemExit) as done:
        main([*command.split(), "--help"])
    assert done.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert ", ".join(detector_names()) in text


def test_an_opencood_target_runs_with_spinning_threads(capsys, monkeypatch, tmp_path):
    """OpenCOOD's forward under asg's PASSIVE wait policy took 7x as long: a command naming an
    OpenCOOD model (`opencood:DIR`, also inside a list of models) sets ACTIVE before torch loads
    (without asg's short spin count, which would cut ACTIVE's spinning short), unless the user set
    the policy; other commands keep PASSIVE and the short spin."""
    import os

    import asg
    from asg import cli
    from asg.registry import TARGET_PREFIXES

    assert TARGET_PREFIXES["opencood"].spins_omp  # read by cli.py before torch may load
    monkeypatch.setattr(asg, "USER_OMP_WAIT_POLICY", None)
    monkeypatch.setattr(asg, "USER_GOMP_SPINCOUNT", None)
    monkeypatch.setenv("OMP_WAIT_POLICY", "PASSIVE")
    monkeypatch.setenv("GOMP_SPINCOUNT", asg.SHORT_SPIN_COUNT)
    cli._spin_for_opencood(["evaluate", "--fusion", "attfuse", "--set", "normal-val"])
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE" and os.environ["GOMP_SPINCOUNT"] == asg.SHORT_SPIN_COUNT
    cli._spin_for_opencood(["bench", "paper", "--models", f"attfuse,opencood:{tmp_path}"])
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE" and "GOMP_SPINCOUNT" not in os.environ
    monkeypatch.setenv("OMP_WAIT_POLICY", "PASSIVE")
    code, _ = run(capsys, "evaluate", "--fusion", f"opencood:{tmp_path / 'missing'}", "--set", "normal-val")
    assert code == 2 and os.environ["OMP_WAIT_POLICY"] == "ACTIVE"
    monkeypatch.setattr(asg, "USER_OMP_WAIT_POLICY", "PASSIVE")  # the user's own choice stands
    monkeypatch.setenv("OMP_WAIT_POLICY", "PASSIVE")
    cli._spin_for_opencood(["evaluate", "--fusion", f"opencood:{tmp_path}"])
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"


def test_evaluate_refuses_a_set_with_no_scenes(capsys, tmp_path):
    """A built set whose frames are all gone (or a split with none) is one line, never AP 0.0 on 0
    frames; the library's evaluate_detector refuses an empty iterable (a one-pass iterator read twice)."""
    import gzip
    import json

    from asg.evaluation import evaluate_detector
    from fakes import OracleDetector

    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "index.json").write_text(json.dumps({"splits": {"all": []}}))
    with gzip.open(empty / "frames.jsonl.gz", "wb"):
        pass
    code, err = run(capsys, "evaluate", "--fusion", "attfuse", "--set", str(empty))
    assert code == 2
    assert_one_line_error(err, "has no scenes to score")
    with pytest.raises(ValueError, match="no scenes"):
        evaluate_detector(OracleDetector(), iter([]))


@pytest.mark.parametrize("command,function,options", [
    ("bench simulate", "asg.benchmarks.simulate:bench_simulate", {"town": "town", "minutes": "minutes", "repeats": "repeats"}),
    ("bench lidar", "asg.benchmarks.lidar:bench_lidar", {"repeats": "repeats"}),
    ("bench detect", "asg.benchmarks.detect:bench_detect", {"frames": "frames", "fusion": "fusion"}),
    ("bench generate", "asg.benchmarks.generate:bench_generate", {"scenes": "scenes", "budget": "budget", "search": "search"}),
    ("bench train", "asg.benchmarks.train:bench_train", {"steps": "steps"}),
    ("bench scale", "asg.benchmarks.scale:bench_scale", {"scenes": "scenes", "budget": "budget"}),
])
def test_a_benchmark_command_runs_its_function_with_the_functions_defaults(command, function, options):
    """A benchmark's command left to its defaults runs what its function does by default (one
    source, asg.benchmarks.defaults; ``asg bench lidar`` once ran 15 repeats where the function said 60)."""
    import importlib
    import inspect

    from asg.cli import build_parser

    args = build_parser(command.split()).parse_args(command.split())
    module, name = function.split(":")
    signature = inspect.signature(getattr(importlib.import_module(module), name))
    for option, parameter in options.items():
        assert getattr(args, option) == signature.parameters[parameter].default, (command, option)
