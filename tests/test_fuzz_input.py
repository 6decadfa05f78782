"""Fuzzing ``semslam run`` (issue 13, 5): random bytes as images, truncated images, random
lines in rgb.txt / depth.txt / groundtruth.txt / calib.txt. Every case must end cleanly:
exit 0 with a stats.json, or exit 2 with exactly one ``error:`` line naming a file of the
sequence, and never a traceback.

Fixed seeds (one per case, so a failing case is reproduced by its test id), a bounded
number of cases on one 6-frame render; sequential runs of the ``orb`` preset, the fastest.
"""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path

import pytest

from semslam.cli.main import main

CASES = 24
LISTS = ("rgb.txt", "depth.txt", "groundtruth.txt", "calib.txt")
TOKENS = ("0", "1", "-1", "nan", "inf", "-inf", "1e308", "-0", "3.5", "0x10", "1_000", "", "#", ",", "é", "\x00",
          "../rgb.txt", "/etc/hostname", "rgb/missing.png", "rgb", "depth/", "calib.txt")


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from semslam.synth import SEQUENCES, render_sequence

    return render_sequence(SEQUENCES["static_xyz"].replace(frames=6, width=320, height=240),
                           tmp_path_factory.mktemp("fuzz") / "static")


def _random_line(rng: random.Random, names: list[str]) -> str:
    """Tokens a list or calibration line may hold, well-formed or not, in random order."""
    pool = [*TOKENS, *names, f"{rng.uniform(-1e10, 1e10)}", f"{rng.uniform(1341846646, 1341846648):.6f}",
            str(rng.randint(-5, 10**6))]
    return rng.choice((" ", ",", "\t")).join(rng.choice(pool) for _ in range(rng.randint(0, 9)))


def _spoil_image(rng: random.Random, path: Path) -> str:
    data = path.read_bytes()
    how = rng.choice(("random bytes", "truncated", "garbage inside a PNG"))
    if how == "random bytes":
        path.write_bytes(rng.randbytes(rng.randint(0, 3000)))
    elif how == "truncated":
        path.write_bytes(data[: rng.randint(0, len(data))])
    else:  # signature and IEND intact: only the decoder can tell
        path.write_bytes(data[: rng.randint(8, 60)] + rng.randbytes(rng.randint(0, 2000)) + data[-12:])
    return f"{how}: {path.parent.name}/{path.name}"


def _spoil_text(rng: random.Random, path: Path, names: list[str]) -> str:
    how = rng.choice(("insert", "replace", "delete", "random bytes"))
    if how == "random bytes":
        path.write_bytes(rng.randbytes(rng.randint(0, 300)))
        return f"random bytes: {path.name}"
    lines = path.read_text(errors="replace").splitlines() if path.exists() else []
    k = rng.randint(0, max(len(lines) - 1, 0))
    if how == "insert" or not lines:
        lines.insert(k, _random_line(rng, names))
    elif how == "replace":
        lines[k] = _random_line(rng, names)
    else:
        del lines[k]
    path.write_text("\n".join(lines) + "\n")
    return f"{how} line {k + 1}: {path.name}"


def spoil(rng: random.Random, seq: Path) -> list[str]:
    """One to three random changes to the sequence; what was done, for the failure message."""
    images = sorted(p for kind in ("rgb", "depth") for p in (seq / kind).glob("*.png"))
    names = [str(p.relative_to(seq)) for p in images]
    done = []
    for _ in range(rng.randint(1, 3)):
        if rng.random() < 0.4:
            done.append(_spoil_image(rng, rng.choice(images)))
        else:
            done.append(_spoil_text(rng, seq / rng.choice(LISTS), names))
    return done


@pytest.mark.parametrize("case", range(CASES))
def test_random_damage_ends_cleanly(case: int, base: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = random.Random(1300 + case)
    seq = Path(shutil.copytree(base, tmp_path / "seq"))
    done = spoil(rng, seq)
    out = tmp_path / "out"
    capsys.readouterr()
    rc = main(["run", str(seq), "--out", str(out), "--quiet", "--no-report", "--map", "none", "--preset", "orb",
               "--sequential"])
    err = capsys.readouterr().err
    assert "Traceback" not in err, done
    if rc == 0:
        stats = json.loads((out / "stats.json").read_text())
        assert stats["frames"] + stats["skipped_frames"] >= 1, done
    else:
        errors = [line for line in err.splitlines() if line.startswith("error:")]
        assert rc == 2 and len(errors) == 1, (done, err)
        assert f"error: {seq}" in errors[0], (done, errors[0])  # names the folder or a file in it
