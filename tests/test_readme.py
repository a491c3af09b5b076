"""The README as users meet it: its two set-up commands and its quick start, run as written."""

import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parent.parent / "README.md"


def blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README.read_text(), flags=re.S)


def test_readme_starts_with_the_two_set_up_commands():
    text = README.read_text()
    first = blocks("bash")[0]
    assert text.index("```bash") < text.index("\n## ")                 # before any section
    commands = [line.split("#")[0].strip() for line in first.splitlines() if line.strip()]
    assert commands == ["make demo", "make test"]
    assert len(text.splitlines()) <= 200


def test_quick_start_runs_as_written_and_its_sanity_line_holds(tmp_path):
    code = blocks("python")[0]
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    m = re.fullmatch(r"trunk (\d+) mm lower; sand carries ([\d.]+) N of the robot's ([\d.]+) N; "
                     r"(\d+) of (\d+) loaded bodies at rest\n", out.stdout)
    assert m, out.stdout
    sink, force, weight, resting, loaded = (float(g) for g in m.groups())
    assert abs(force - weight) <= 0.01 * weight and 50 <= sink <= 150 and resting == loaded > 0
    assert m.group(0).strip() in README.read_text()                  # the README shows what it prints
