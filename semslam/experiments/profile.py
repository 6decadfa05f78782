"""Profiling a SLAM run (``semslam bench --profile``): where the time goes, per thread and
per stage, measured by sampling, not guessed.

The run is an ordinary ``semslam run`` in a child process under py-spy (a sampling
profiler on PyPI that reads the stacks from outside, so the run is not slowed by
instrumentation and every thread and the BA worker process are seen). Without ``--idle``
py-spy records only threads that are running, so a thread's samples / rate is its CPU
time; the run's own ``stats.json`` gives the wall time per stage. From the raw stacks we
report:

- CPU seconds per thread (tracking = the main thread, local mapping, loop closing, the
  semantic thread, the reader, the BA worker process);
- CPU seconds per stage: the first frame of a stack (from the root) whose function is a
  known stage of that thread (``STAGES``), else "other";
- the top functions by self time (the leaf frame) and by total time (anywhere on the stack).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from semslam.errors import ConfigError

if TYPE_CHECKING:
    from semslam.experiments.bench import Variant

#: Stage name -> functions that start it, ``name`` (a function in semslam) or
#: ``file-suffix:name``; the first match from the stack's root wins.
STAGES: dict[str, tuple[str, ...]] = {
    "imports": ("<frozen importlib._bootstrap>:_find_and_load",),
    "build the system": ("assembly.py:assemble",),
    "semantic wait": ("before_extraction",),
    "extract": ("extract",),
    "track frame": ("_track_frame",),
    "local map": ("_track_local_map",),
    "multiview": ("_remove_moving",),
    "keyframe": ("_create_keyframe", "_initialize"),
    "decode": ("load", "read_rgb", "read_depth"),
    "segment": ("segment",),
    "srm": ("refine_segmentation",),
    "new keyframe": ("_process_new_keyframe",),
    "point culling": ("_cull_points",),
    "triangulation": ("_create_new_points",),
    "fusion": ("_search_in_neighbours", "fuse"),
    "local BA (build/apply)": ("_local_bundle_adjustment",),
    "keyframe culling": ("_cull_keyframes",),
    "loop detection": ("_detect_loop",),
    "loop SE3": ("_compute_transform",),
    "loop correction": ("_correct_loop",),
    "global BA (build/apply)": ("global_bundle_adjustment",),
    "bundle adjustment (GTSAM)": ("bundle_adjust",),
    "pose graph (GTSAM)": ("optimize_pose_graph",),
}
_STAGE_OF = {fn: stage for stage, fns in STAGES.items() for fn in fns}
#: Leaves where a thread blocks on a queue in C without py-spy seeing it idle (measured:
#: the pools' idle workers showed up as "active"): waiting, not CPU.
_WAIT_LEAVES = ("_worker (concurrent/futures/thread.py",)
#: The entry chain every tracking sample passes through: left out of "top by total".
_ENTRY = ("<module>", "cli/", "pipeline.py)", "api.py)", "assembly.py)", "orb/tracker.py)")
_FRAME = re.compile(r"^(?P<func>[^ ]+) \((?P<file>[^:]*)(?::(?P<line>\d+))?\)$")
_TOKEN = re.compile(r'(?:[^;"]|"[^"]*")+')


@dataclass
class Profile:
    """Sampled CPU time of one run: per thread, per (thread, stage), per function."""

    rate_hz: float
    thread_s: dict[str, float] = field(default_factory=dict)
    stage_s: dict[tuple[str, str], float] = field(default_factory=dict)
    self_s: list[tuple[str, float]] = field(default_factory=list)
    total_s: list[tuple[str, float]] = field(default_factory=list)

    def to_dict(self) -> dict[str, object]:
        return {
            "rate_hz": self.rate_hz,
            "cpu_s_per_thread": self.thread_s,
            "cpu_s_per_stage": [{"thread": t, "stage": s, "cpu_s": v} for (t, s), v in self.stage_s.items()],
            "top_self_s": [{"function": f, "cpu_s": v} for f, v in self.self_s],
            "top_total_s": [{"function": f, "cpu_s": v} for f, v in self.total_s],
        }


def _split_tokens(tokens: list[str]) -> tuple[list[str], str, list[str]]:
    """(process tokens, thread name, remaining frames) of one stack; py-spy names a child
    process of the run by a second ``process`` token."""
    processes, thread, i = [], "", 0
    while i < len(tokens) and tokens[i].startswith(("process ", "thread ")):
        if tokens[i].startswith("process "):
            processes.append(tokens[i])
        else:
            thread = tokens[i].split(":", 1)[1].strip() if ":" in tokens[i] else ""
        i += 1
    return processes, thread, tokens[i:]


def _child_labels(stacks: list[tuple[list[str], str, list[str], int]]) -> dict[str, str]:
    """Label of each child process (by its pid token) from all of its stacks. The command
    line py-spy shows is read once, and can be the parent's when the child is first seen
    between fork and exec (measured on CI: the BA worker appeared as "other process"), so a
    spawned worker is also recognised by multiprocessing's spawn entry on its stacks."""
    text: defaultdict[str, list[str]] = defaultdict(list)
    for processes, _, frames, _ in stacks:
        if len(processes) > 1:
            key = processes[-1].split(":", 1)[0]
            text[key].append(processes[-1])
            text[key].extend(frames)
    labels = {}
    for key, parts in text.items():
        joined = ";".join(parts)
        if "reconstruction/mapping_worker.py" in joined:
            labels[key] = "maps worker process"
        elif "multiprocessing.spawn" in joined or "spawn_main (multiprocessing/spawn.py" in joined:
            labels[key] = "BA worker process"
        else:
            labels[key] = "other process"
    return labels


def _thread_label(processes: list[str], thread: str, children: dict[str, str]) -> str:
    if len(processes) > 1:
        return children[processes[-1].split(":", 1)[0]]
    return {"MainThread": "tracking (main)", "": "main"}.get(thread, thread)


def _stage(frame: str) -> str | None:
    m = _FRAME.match(frame)
    if m is None:
        return None
    func, path = m.group("func"), m.group("file")
    if "semslam" in path and func in _STAGE_OF:
        return _STAGE_OF[func]
    for key, stage in _STAGE_OF.items():
        suffix, _, name = key.rpartition(":")
        if suffix and name == func and path.endswith(suffix):
            return stage
    return None


def _function(frame: str) -> str:
    m = _FRAME.match(frame)
    if m is None:
        return frame
    path = m.group("file")
    short = path.split("site-packages/")[-1]
    return f"{m.group('func')} ({short})"


def parse_raw(text: str, rate_hz: float, top: int = 15) -> Profile:
    """Aggregate py-spy's ``--format raw`` output (one ``stack count`` line per stack)."""
    threads: Counter[str] = Counter()
    stages: Counter[tuple[str, str]] = Counter()
    self_n: Counter[str] = Counter()
    total_n: Counter[str] = Counter()
    stacks = []
    for line in text.splitlines():
        stack, _, count_txt = line.rpartition(" ")
        if stack and count_txt.isdigit():
            stacks.append((*_split_tokens(_TOKEN.findall(stack)), int(count_txt)))
    children = _child_labels(stacks)
    for processes, thread, frames, n in stacks:
        label = _thread_label(processes, thread, children)
        if frames and frames[-1].startswith(_WAIT_LEAVES):
            continue
        threads[label] += n
        stage = next((st for fr in frames if (st := _stage(fr)) is not None), "other")
        stages[(label, stage)] += n
        if frames:
            self_n[_function(frames[-1])] += n
        for fn in dict.fromkeys(_function(fr) for fr in frames):
            if "semslam/" in fn and not any(e in fn for e in _ENTRY):
                total_n[fn] += n
    to_s = 1.0 / rate_hz
    by_thread: defaultdict[str, list[tuple[str, float]]] = defaultdict(list)
    for (t, s), v in stages.items():
        by_thread[t].append((s, v * to_s))
    stage_s = {(t, s): v for t in sorted(by_thread, key=lambda t: -threads[t])
               for s, v in sorted(by_thread[t], key=lambda x: -x[1])}
    return Profile(rate_hz, {t: n * to_s for t, n in threads.most_common()}, stage_s,
                   [(f, n * to_s) for f, n in self_n.most_common(top)],
                   [(f, n * to_s) for f, n in total_n.most_common(top)])


def profile_run(run_args: list[str], out_dir: Path, rate_hz: int = 250) -> Profile:
    """Run ``semslam run <run_args>`` under py-spy; return the parsed profile and keep the
    raw stacks in ``out_dir/profile.raw.txt`` (flamegraph.pl and speedscope read them)."""
    py_spy = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
    if not Path(py_spy).exists():
        raise ConfigError("--profile needs py-spy (pip install py-spy)")
    out_dir.mkdir(parents=True, exist_ok=True)
    raw = out_dir / "profile.raw.txt"
    cmd = [py_spy, "record", "-r", str(rate_hz), "-t", "-s", "-f", "raw", "-o", str(raw), "--",
           sys.executable, "-m", "semslam.cli.main", "run", *run_args]
    raw.unlink(missing_ok=True)
    proc = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    # py-spy 0.4 with --subprocesses can end with "No child process (os error 10)" after it has
    # written every sample (it waits for a child the run already reaped): the samples count,
    # the exit code does not. The run's own outcome is in its stats.json.
    if not raw.is_file() or "Wrote raw" not in proc.stderr + proc.stdout:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        raise ConfigError(f"profiling failed (py-spy exit {proc.returncode}): {tail[0]}")
    return parse_raw(raw.read_text(), rate_hz)


def profile_table(profile: Profile, wall_stage_ms: dict[str, float] | None = None) -> str:
    """Markdown: CPU per thread and stage, then the top functions."""
    lines = ["| thread | CPU s | stage | CPU s |", "|---|---|---|---|"]
    for (t, s), v in profile.stage_s.items():
        lines.append(f"| {t} | {profile.thread_s[t]:.2f} | {s} | {v:.2f} |")
    if wall_stage_ms:
        lines += ["", "| tracking stage (wall, median per frame) | ms |", "|---|---|"]
        lines += [f"| {k} | {v:.1f} |" for k, v in wall_stage_ms.items()]
    lines += ["", "| top functions by self CPU | s |", "|---|---|"]
    lines += [f"| `{f}` | {v:.2f} |" for f, v in profile.self_s]
    lines += ["", "| top functions by total CPU | s |", "|---|---|"]
    lines += [f"| `{f}` | {v:.2f} |" for f, v in profile.total_s]
    return "\n".join(lines)


def profile_variants(variants: list["Variant"], sequences: list[str], data: Path, out: Path,
                     frames: int | None = None, rate_hz: int = 250) -> list[dict[str, object]]:
    """Each variant on each (rendered, cached) sequence as a user runs it (threaded), under
    the profiler; one record per run: the run's RunResult and its profile."""
    import json
    from dataclasses import replace

    from semslam.config import load_config
    from semslam.core.types import RunResult
    from semslam.synth import SEQUENCES, ensure_rendered

    for v in variants:
        load_config(v.preset, list(v.overrides))  # a bad variant fails before any rendering
    records = []
    for name in sequences:
        if name not in SEQUENCES:
            raise ConfigError(f"--sequences: unknown {name} (known: {', '.join(SEQUENCES)})")
        synth_cfg = SEQUENCES[name] if frames is None else replace(SEQUENCES[name], frames=frames)
        ensure_rendered(synth_cfg, data / name)
        for v in variants:
            run_dir = out / v.label / name
            args = [str(data / name), "--out", str(run_dir), "--preset", v.preset, "--quiet", "--no-report"]
            for o in v.overrides:
                args += ["--set", o]
            profile = profile_run(args, run_dir)
            result = RunResult.from_dict(json.loads((run_dir / "stats.json").read_text()))
            records.append({"variant": v.label, "sequence": name, "result": result, "profile": profile})
    return records
