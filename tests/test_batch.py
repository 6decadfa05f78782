"""``semslam batch PLAN.yaml``: the same jobs on a local Ray instance and in-process
(``--no-ray``) give the same summary; every number in it is the run's own ``stats.json``;
a job on a missing folder fails with its one line and the batch completes; a second run
skips finished jobs; the summary page's plots render in headless Chromium."""

from __future__ import annotations

import json
import re
import shutil
import statistics
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from semslam.cli.main import main
from semslam.experiments.batch_jobs import finished_record
from semslam.experiments.batch_plan import load_plan

FRAMES = 12  # per run: enough to initialise, make keyframes and evaluate ATE
SEQS = ("xyz", "rpy")
VARIANTS = ("orb", "orb-600")
REPEATS = 2
OK_JOBS = len(SEQS) * len(VARIANTS) * REPEATS


def _render(root: Path, name: str, *args: str) -> Path:
    assert main(["synth", str(root / name), "--sequence", "static_xyz", "-n", str(FRAMES), "--width", "320",
                 "--height", "240", "--quiet", *args]) == 0
    return root / name


@pytest.fixture(scope="module")
def plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two tiny renders and a folder that does not exist x orb and a --set variant x 2
    repeats (seeded), sequential (deterministic) runs."""
    root = tmp_path_factory.mktemp("batch")
    xyz, rpy = _render(root, "xyz"), _render(root, "rpy", "--motion", "rpy")
    doc = {"sequences": [str(xyz), str(rpy), str(root / "missing")],
           "variants": ["orb", {"label": "orb-600", "preset": "orb", "set": ["features.n_features=600"]}],
           "repeats": REPEATS, "seeds": [3, 4], "frames": FRAMES, "sequential": True, "report": False,
           "num_cpus": 1}
    path = root / "plan.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.fixture(scope="module")
def ray_out(plan: Path) -> Path:
    """The plan on a local Ray instance of 2 CPUs the batch starts and shuts down itself."""
    ray = pytest.importorskip("ray")
    out = plan.parent / "ray"
    assert main(["batch", str(plan), "--out", str(out), "--num-cpus", "2", "--quiet"]) == 1  # 1: jobs failed
    assert not ray.is_initialized()
    return out


@pytest.fixture(scope="module")
def local_out(plan: Path) -> Path:
    out = plan.parent / "local"
    assert main(["batch", str(plan), "--out", str(out), "--no-ray", "--quiet"]) == 1
    return out


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def _check_against_runs(summary: dict, out: Path) -> None:
    """Every ok job's numbers are its stats.json's; its config has the variant and the
    repeat's seed; each group's median and range are those of its jobs."""
    for job in summary["jobs"]:
        if job["status"] != "ok":
            continue
        folder = out / job["sequence"] / job["variant"] / f"r{job['repeat']}"
        assert Path(job["out_dir"]) == folder
        stats = json.loads((folder / "stats.json").read_text())
        config = json.loads((folder / "config.json").read_text())
        assert job["ate_rmse_m"] == stats["ate"]["rmse"] and job["ate_rmse_m"] < 0.05
        assert job["ms_per_frame_median"] == stats["ms_per_frame"]["median"]
        assert job["lost_frames"] == stats["lost_frames"] and job["frames"] == stats["frames"] == FRAMES
        assert config["seed"] == [3, 4][job["repeat"]] and config["slam"]["sequential"] is True
        assert config["features"]["n_features"] == (600 if job["variant"] == "orb-600" else 1000)
    for g in summary["groups"]:
        cell = [j for j in summary["jobs"] if (j["sequence"], j["variant"]) == (g["sequence"], g["variant"])]
        ate = [j["ate_rmse_m"] for j in cell if j["status"] == "ok"]
        assert g["n_runs"] == REPEATS and g["n_ok"] == len(ate) and g["n_failed"] == REPEATS - len(ate)
        if ate:
            assert g["ate_rmse_m"] == {"median": statistics.median(ate), "min": min(ate), "max": max(ate)}
        else:
            assert g["ate_rmse_m"] is None


def test_ray_and_in_process_run_the_same_jobs(ray_out: Path, local_out: Path) -> None:
    ray_sum, local_sum = _summary(ray_out), _summary(local_out)
    assert ray_sum["executor"]["ray"] is True and local_sum["executor"]["ray"] is False
    for s, out in ((ray_sum, ray_out), (local_sum, local_out)):
        _check_against_runs(s, out)
        assert (s["n_jobs"], s["n_ok"], s["n_failed"]) == (OK_JOBS + len(VARIANTS) * REPEATS, OK_JOBS,
                                                           len(VARIANTS) * REPEATS)
        assert s.keys() == ray_sum.keys() and [g.keys() for g in s["groups"]] == [g.keys() for g in ray_sum["groups"]]
    key = ("sequence", "variant", "repeat", "status", "error", "frames", "keyframes")
    assert [[j[k] for k in key] for j in ray_sum["jobs"]] == [[j[k] for k in key] for j in local_sum["jobs"]]
    # Sequential runs are deterministic: the same ATE wherever the job ran.
    assert [j["ate_rmse_m"] for j in ray_sum["jobs"]] == [j["ate_rmse_m"] for j in local_sum["jobs"]]
    md = (local_out / "summary.md").read_text()
    g = local_sum["groups"][0]
    ate = g["ate_rmse_m"]
    assert (f"| xyz | orb | 2 / 2 | {ate['median'] * 100:.2f} [{ate['min'] * 100:.2f}-{ate['max'] * 100:.2f}] |"
            in md)


def test_failed_job_is_one_line_and_the_batch_completes(ray_out: Path, local_out: Path) -> None:
    for out in (ray_out, local_out):
        failed = [j for j in _summary(out)["jobs"] if j["status"] != "ok"]
        assert {j["sequence"] for j in failed} == {"missing"} and len(failed) == len(VARIANTS) * REPEATS
        for j in failed:
            assert j["error"] == f"DataError: {out.parent / 'missing'}: sequence not found"
            assert json.loads((Path(j["out_dir"]) / "job.json").read_text())["status"] == "failed"
        assert "missing/orb/r1: DataError:" in (out / "summary.md").read_text()


def test_second_run_skips_finished_jobs(plan: Path, local_out: Path, capsys: pytest.CaptureFixture[str]) -> None:
    marks = {p: p.stat().st_mtime_ns for p in local_out.glob("*/*/r*/*.json")}
    assert len(marks) == 3 * OK_JOBS + len(VARIANTS) * REPEATS  # job, stats, config; job.json of failed ones
    capsys.readouterr()
    assert main(["batch", str(plan), "--out", str(local_out), "--no-ray", "--quiet"]) == 1
    assert f"{OK_JOBS} of {OK_JOBS + len(VARIANTS) * REPEATS} jobs finished earlier" in capsys.readouterr().err
    again = _summary(local_out)
    assert again["n_resumed"] == OK_JOBS and again["n_ok"] == OK_JOBS
    for path, mtime in marks.items():  # finished jobs untouched; failed ones tried again
        assert (path.stat().st_mtime_ns == mtime) == ("missing" not in path.parts), path
    _check_against_runs(again, local_out)
    # A job the plan now describes differently is not finished: it runs again.
    job = next(j for j in load_plan(plan).jobs(local_out.resolve()) if j.sequence == "xyz")
    assert finished_record(job) is not None
    for changed in (replace(job, overrides=("features.n_features=700",)), replace(job, seed=9),
                    replace(job, max_frames=FRAMES - 2)):
        assert finished_record(changed) is None


def test_plan_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cases = {"variants: [orb]\n": "sequences: expected a non-empty list",
             "sequences: [x]\nvariants: [nope]\n": "variant 'nope': unknown preset 'nope'",
             "sequences: [x]\nvariants: [orb]\nrepeats: 2\nseeds: [1]\n": "seeds: 1 seeds for 2 repeats",
             "sequences: [x]\nvariants: [orb]\nthreads: 2\n": "unknown key 'threads'",
             "sequences: [a/x, b/x]\nvariants: [orb]\n": "sequence label 'x' appears twice",
             "sequences: [{synth: static_xyz, layout: 500}]\nvariants: [orb]\n": "unknown layout 500",
             "sequences: [{path: x, layout: 1}]\nvariants: [orb]\n": "layout: apply to synth: sequences"}
    for i, (text, message) in enumerate(cases.items()):
        path = tmp_path / f"p{i}.yaml"
        path.write_text(text)
        assert main(["batch", str(path), "--no-ray", "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err
        assert f"error: {path}: " in err and message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o").exists()


def test_without_ray_the_cli_says_use_no_ray(plan: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the batch extra were not installed
    assert main(["batch", str(plan), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: Ray is not installed") and "--no-ray" in err and "\n" not in err


#: Appended to a copy of the page: what the browser laid out, into the DOM for --dump-dom.
_PROBE = """<script>
const r = e => e.getBoundingClientRect();
const plots = [...document.querySelectorAll('figure.plot')].map(f => {
  const svg = f.querySelector('svg'), runs = {};
  f.querySelectorAll('g[id*="-runs-"]').forEach(g => {
    runs[g.id] = [...g.querySelectorAll('use')].filter(u => r(u).width > 0 && r(u).height > 0).length; });
  return {id: f.id, width: r(svg).width, height: r(svg).height, runs: runs};
});
const pre = document.createElement('pre'); pre.id = 'probe'; pre.textContent = JSON.stringify(plots);
document.body.appendChild(pre);
</script>"""


def test_summary_page_plots_render_in_chromium(ray_out: Path, tmp_path: Path) -> None:
    """The page's plots as the browser lays them out: both SVGs have a size, and each
    variant's dots are drawn once per finished repeat, with a size on screen."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("Debian's chromium is not installed (apt-get install chromium)")
    page = (ray_out / "summary.html").read_text()
    assert not re.search(r"""(?:src|href)=["']?(?:https?:|//)""", page)  # self-contained: nothing fetched
    probe = tmp_path / "probe.html"
    probe.write_text(page.replace("</body>", _PROBE + "</body>"))
    dom = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1280,2000",
                          "--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=120).stdout
    found = re.search(r'<pre id="probe">(.*?)</pre>', dom, re.S)
    assert found, dom[-2000:]
    plots = json.loads(found.group(1).replace("&quot;", '"'))
    assert [p["id"] for p in plots] == ["ate-plot", "ms-plot"]
    per_variant = OK_JOBS // len(VARIANTS)
    for p in plots:
        assert p["width"] > 300 and p["height"] > 150
        assert p["runs"] == {f"{p['id'][:-5]}-runs-{i}": per_variant for i in range(len(VARIANTS))}


def test_bench_repeats_report_the_spread(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``semslam bench --repeats 2`` runs through the batch runner: a row per run (its
    stats.json), and per sequence x variant the median and range of those rows."""
    out = tmp_path / "runs"
    assert main(["bench", "--presets", "orb", "--sequences", "static_xyz", "--frames", "10", "--repeats", "2",
                 "--data", str(tmp_path / "data"), "--out", str(out), "--json", str(tmp_path / "b.json")]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((tmp_path / "b.json").read_text())
    assert [(r["variant"], r["repeat"]) for r in doc["results"]] == [("orb", 0), ("orb", 1)] and doc["failed"] == []
    ate = [json.loads((out / "orb" / "static_xyz" / f"r{k}" / "stats.json").read_text())["ate"]["rmse"]
           for k in (0, 1)]
    assert [r["ate_rmse_m"] for r in doc["results"]] == ate
    (group,) = doc["groups"]
    assert group["n_ok"] == 2 and group["ate_rmse_m"] == {"median": statistics.median(ate), "min": min(ate),
                                                          "max": max(ate)}
    assert "| static_xyz | 0 | orb (r1) | 10 (" in printed and "| static_xyz | orb | 2 / 2 |" in printed


def test_plan_renders_a_synthetic_sequence_in_another_room(tmp_path: Path) -> None:
    """``layout:`` renders the sequence in that room, into a folder (and label) of its own,
    next to the same sequence in the office."""
    from semslam.experiments.batch import render_synthetic

    path = tmp_path / "plan.yaml"
    path.write_text(f"sequences:\n  - synth: static_xyz\n  - synth: static_xyz\n    layout: 1\n"
                    f"variants: [orb]\nframes: 2\ndata: {tmp_path / 'data'}\n")
    plan = render_synthetic(load_plan(path), lambda _: None)
    assert [s.label for s in plan.sequences] == ["static_xyz", "static_xyz_layout1"]
    office, lounge = (json.loads((Path(s.source) / "sequence.json").read_text())["config"] for s in plan.sequences)
    assert (office["layout"], lounge["layout"]) == (0, 1) and Path(plan.sequences[1].source).name == "static_xyz_layout1"
    assert plan.to_dict()["sequences"][1] == {"label": "static_xyz_layout1", "source": plan.sequences[1].source,
                                              "synth": "static_xyz", "layout": 1}
