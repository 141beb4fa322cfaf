"""``asg report``: one self-contained page that headless Chromium (Debian's chromium package)
opens with every inline image decoded; no network reference in it."""
import re
import shutil
import subprocess

from asg.cli import main

from test_cli import assert_one_line_error, run
from test_robustness import oracle_run


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    raise AssertionError("Chromium is needed for this test: apt-get install chromium (make setup installs it)")


def test_report_renders_in_headless_chromium(capsys, tmp_path):
    out = oracle_run(tmp_path, 2, "--budget", "4")
    assert main(["report", str(out)]) == 0
    page = (out / "report.html").read_text()
    assert "s0" in page and "s1" in page and "after ACS" in page
    assert not re.search(r"(src|href)=['\"]https?:", page)  # self-contained
    dom = subprocess.run([_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom",
                          (out / "report.html").as_uri()], capture_output=True, text=True, timeout=120).stdout
    total = int(re.search(r'data-images="(\d+)"', dom).group(1))
    decoded = int(re.search(r'data-images-ok="(\d+)"', dom).group(1))
    assert total == decoded == 3  # the loss chart and one row of three views per scene
    capsys.readouterr()


def test_report_of_nothing_is_one_line(capsys, tmp_path):
    code, err = run(capsys, "report", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, "no run folder")
