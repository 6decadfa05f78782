"""A batch plan (``semslam batch PLAN.yaml``): sequences x variants x repeats, expanded into
jobs, each one ``semslam run`` worth of work in its own output folder.

The plan is read and checked here once, so a typo fails before any job starts (one
``ConfigError`` line naming the file and the key). Layout of the YAML::

    sequences:                  # folders, dataset names, or synthetic renders
      - /data/rgbd_dataset_freiburg3_walking_xyz
      - tum/fr3_walking_xyz     # a name: opened as `semslam run NAME` opens it
      - synth: walking_xyz      # rendered (cached) into `data`
        frames: 300             # optional, per sequence
      - synth: static_xyz       # in another room (`semslam synth --layout`): the lounge,
        layout: 1               # held out from every shipped network; label static_xyz_layout1
      - {path: /data/seq, label: seq-a}
    variants:                   # presets with --set overrides
      - orb                     # a bare preset is its own label
      - orb-noloop:orb:slam.loop_closing=false    # semslam bench's syntax
      - {label: orb-s, preset: orb, set: [dynamics.semantic=true]}
    repeats: 3                  # runs per sequence x variant (threaded runs differ)
    seeds: [0, 1, 2]            # optional: repeat k runs with --set seed=seeds[k]
    frames: 300                 # optional: frames per run (synthetic: rendered this long)
    num_cpus: 2                 # Ray CPUs per job (SLAM's own threads fit in them)
    sequential: false           # true: slam.sequential for every job (deterministic runs)
    report: true                # each run's report.html (plots: ~1 s per run)
    data: out/batch/data        # where synthetic sequences are rendered
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from semslam.config import load_config
from semslam.config.load import _read_yaml as read_yaml_mapping  # presets' reader: the same one-line errors
from semslam.errors import ConfigError

#: Job folders under the batch output: one per sequence, variant and repeat.
DEFAULT_LAYOUT = "{sequence}/{variant}/r{repeat}"
#: Characters allowed in a sequence or variant label (they become folder names).
_LABEL = re.compile(r"^[A-Za-z0-9_.+=@,-]+$")
_PLAN_KEYS = {"sequences", "variants", "repeats", "seeds", "frames", "num_cpus", "sequential", "report", "data"}


@dataclass(frozen=True)
class Variant:
    """A preset with ``--set`` overrides, under a label (a column of a results table)."""

    label: str
    preset: str
    overrides: tuple[str, ...] = ()

    @classmethod
    def parse(cls, text: str) -> "Variant":
        """``label:preset:key=value,...``; a bare preset name is its own label."""
        parts = text.split(":")
        if len(parts) == 1:
            return cls(parts[0], parts[0])
        if len(parts) > 3 or not parts[0] or not parts[1]:
            raise ConfigError(f"--variant {text!r}: expected label:preset[:key=value,...]")
        rest = parts[2] if len(parts) == 3 else ""
        return cls(parts[0], parts[1], tuple(o for o in rest.split(",") if o))


@dataclass(frozen=True)
class SequenceSpec:
    """One sequence of a plan: ``source`` is a folder or a dataset name, passed unchanged to
    the sequence opening ``semslam run`` uses; or ``synth`` names a synthetic sequence,
    rendered into the plan's data folder (``source`` is then set to that folder)."""

    label: str
    source: str = ""
    synth: str = ""
    frames: int | None = None  # synthetic only: frames to render
    layout: int | None = None  # synthetic only: the room (None: the sequence's own, the office)

    @property
    def render_name(self) -> str:
        """The render's folder name under the plan's data folder (one per sequence and room)."""
        return self.synth if self.layout is None else f"{self.synth}_layout{self.layout}"


@dataclass(frozen=True)
class Job:
    """One run: what ``semslam run SOURCE --preset P --set ...`` would do, into ``out_dir``."""

    sequence: str  # the sequence's label
    source: str  # folder or dataset name handed to the sequence opening
    variant: str
    preset: str
    overrides: tuple[str, ...]
    repeat: int
    seed: int | None
    max_frames: int | None
    num_cpus: float
    out_dir: Path
    report: bool = True  # the run's report.html

    @property
    def key(self) -> str:
        return f"{self.sequence}/{self.variant}/r{self.repeat}"

    @property
    def run_overrides(self) -> list[str]:
        """The variant's overrides, then the repeat's seed."""
        return [*self.overrides, *([] if self.seed is None else [f"seed={self.seed}"])]


@dataclass
class Plan:
    """Sequences x variants x repeats, and how each job runs."""

    sequences: list[SequenceSpec]
    variants: list[Variant]
    repeats: int = 1
    seeds: list[int] | None = None
    frames: int | None = None
    num_cpus: float = 1.0
    sequential: bool = False
    report: bool = True
    data: Path = Path("out/batch/data")
    layout: str = DEFAULT_LAYOUT
    where: str = "plan"  # the plan's file, for error messages
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.check()

    def check(self) -> None:
        """Refuse what no job could run, before any job starts."""
        w = self.where
        if not self.sequences:
            raise ConfigError(f"{w}: sequences: at least one sequence is needed")
        if not self.variants:
            raise ConfigError(f"{w}: variants: at least one variant (a preset name) is needed")
        if self.repeats < 1:
            raise ConfigError(f"{w}: repeats: expected a whole number >= 1, got {self.repeats}")
        if self.seeds is not None and len(self.seeds) != self.repeats:
            raise ConfigError(f"{w}: seeds: {len(self.seeds)} seeds for {self.repeats} repeats (give one per repeat)")
        if self.frames is not None and self.frames < 2:
            raise ConfigError(f"{w}: frames: expected at least 2, got {self.frames}")
        if self.num_cpus <= 0:
            raise ConfigError(f"{w}: num_cpus: expected a positive number, got {self.num_cpus}")
        for kind, labels in (("sequence", [s.label for s in self.sequences]),
                             ("variant", [v.label for v in self.variants])):
            for label in labels:
                if not _LABEL.match(label):
                    raise ConfigError(f"{w}: {kind} label {label!r}: use letters, digits and _.+=@,- "
                                      f"(it becomes a folder name; give `label:`)")
            dup = sorted({x for x in labels if labels.count(x) > 1})
            if dup:
                raise ConfigError(f"{w}: {kind} label {dup[0]!r} appears twice (give each a distinct `label:`)")
        for v in self.variants:  # a bad preset or --set fails here, not in every job
            try:
                load_config(v.preset, [*v.overrides, *self._common_overrides()])
            except ConfigError as exc:
                raise ConfigError(f"{w}: variant {v.label!r}: {exc}") from None

    def _common_overrides(self) -> list[str]:
        return ["slam.sequential=true"] if self.sequential else []

    def jobs(self, out: Path) -> list[Job]:
        """Every job, repeat-major (a partial batch has every cell once before any twice),
        each in ``out / layout``."""
        jobs = []
        for k in range(self.repeats):
            for s in self.sequences:
                for v in self.variants:
                    seed = None if self.seeds is None else self.seeds[k]
                    folder = self.layout.format(sequence=s.label, variant=v.label, repeat=k)
                    jobs.append(Job(s.label, s.source, v.label, v.preset, (*v.overrides, *self._common_overrides()),
                                    k, seed, self.frames, self.num_cpus, out / folder, self.report))
        return jobs

    def with_sources(self, sources: dict[str, str]) -> "Plan":
        """The plan with synthetic sequences' ``source`` set to their rendered folders."""
        seqs = [replace(s, source=sources.get(s.label, s.source)) for s in self.sequences]
        return replace(self, sequences=seqs)

    def to_dict(self) -> dict[str, Any]:
        return {"sequences": [{k: v for k, v in vars(s).items() if v not in ("", None)} for s in self.sequences],
                "variants": [{"label": v.label, "preset": v.preset, "set": list(v.overrides)} for v in self.variants],
                "repeats": self.repeats, "seeds": self.seeds, "frames": self.frames, "num_cpus": self.num_cpus,
                "sequential": self.sequential, "report": self.report, "data": str(self.data)}


def load_plan(path: str | Path, repeats: int | None = None, frames: int | None = None) -> Plan:
    """Read and check a plan file; ``repeats`` / ``frames`` override the file's."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: plan file not found")
    return plan_from_dict(read_yaml_mapping(path), str(path), repeats=repeats, frames=frames)


def plan_from_dict(data: dict[str, Any], where: str = "plan", repeats: int | None = None,
                   frames: int | None = None) -> Plan:
    unknown = sorted(set(data) - _PLAN_KEYS)
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(_PLAN_KEYS))})")
    seeds = data.get("seeds")
    if seeds is not None and (not isinstance(seeds, list) or not all(isinstance(s, int) for s in seeds)):
        raise ConfigError(f"{where}: seeds: expected a list of whole numbers, got {seeds!r}")
    n_repeats = _number(data, "repeats", int, where, len(seeds) if seeds else 1) if repeats is None else repeats
    if repeats is not None and seeds is not None:  # --repeats on the command line: the plan's first seeds
        seeds = seeds[:repeats]
    return Plan(
        sequences=[_sequence(item, where) for item in _list(data, "sequences", where)],
        variants=[_variant(item, where) for item in _list(data, "variants", where)],
        repeats=n_repeats, seeds=seeds,
        frames=_number(data, "frames", int, where, None) if frames is None else frames,
        num_cpus=_number(data, "num_cpus", float, where, 1.0),
        sequential=_bool(data, "sequential", where, False), report=_bool(data, "report", where, True),
        data=Path(str(data.get("data", "out/batch/data"))), where=where,
    )


def _list(data: dict[str, Any], key: str, where: str) -> list[Any]:
    value = data.get(key)
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{where}: {key}: expected a non-empty list")
    return value


def _number(data: dict[str, Any], key: str, kind: type, where: str, default: Any) -> Any:
    value = data.get(key, default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and not isinstance(value, int)):
        raise ConfigError(f"{where}: {key}: expected a {'whole ' if kind is int else ''}number, got {value!r}")
    return kind(value)


def _bool(data: dict[str, Any], key: str, where: str, default: bool) -> bool:
    value = data.get(key, default)
    if not isinstance(value, bool):
        raise ConfigError(f"{where}: {key}: expected true or false, got {value!r}")
    return value


def default_label(source: str) -> str:
    """The last part of a folder or dataset name (``tum/fr3_walking_xyz`` -> ``fr3_walking_xyz``)."""
    return Path(source.rstrip("/")).name or source


def absolute_source(source: str) -> str:
    """An existing folder as an absolute path (a job may run in another working directory,
    on another node); anything else (a dataset name) unchanged."""
    path = Path(source).expanduser()
    return str(path.resolve()) if path.exists() else source


def _sequence(item: Any, where: str) -> SequenceSpec:
    if isinstance(item, str) and item:
        return SequenceSpec(default_label(item), source=absolute_source(item))
    if not isinstance(item, dict):
        raise ConfigError(f"{where}: sequences: expected a folder, a dataset name or a mapping, got {item!r}")
    keys = set(item)
    if not keys <= {"path", "synth", "label", "frames", "layout"} or len(keys & {"path", "synth"}) != 1:
        raise ConfigError(f"{where}: sequences: {item!r}: give one of path: or synth: (with optional label:, "
                          f"and frames: and layout: for synth:)")
    frames = _number(item, "frames", int, where, None)
    layout = _number(item, "layout", int, where, None)
    if "synth" in item:
        from semslam.synth import SEQUENCES
        from semslam.synth.layouts import get_layout

        name = str(item["synth"])
        if name not in SEQUENCES:
            raise ConfigError(f"{where}: sequences: unknown synthetic sequence {name!r} "
                              f"(known: {', '.join(SEQUENCES)})")
        if layout is not None:
            try:
                get_layout(layout)
            except ConfigError as exc:
                raise ConfigError(f"{where}: sequences: {item!r}: {exc}") from None
        spec = SequenceSpec("", synth=name, frames=frames, layout=layout)
        return replace(spec, label=str(item.get("label", spec.render_name)))
    if frames is not None or layout is not None:
        raise ConfigError(f"{where}: sequences: {item!r}: frames: and layout: apply to synth: sequences (use the "
                          f"plan's frames: to limit every run)")
    source = str(item["path"])
    return SequenceSpec(str(item.get("label", default_label(source))), source=absolute_source(source))


def _variant(item: Any, where: str) -> Variant:
    if isinstance(item, str) and item:
        return Variant.parse(item)
    if not isinstance(item, dict) or "preset" not in item or not set(item) <= {"label", "preset", "set"}:
        raise ConfigError(f"{where}: variants: expected a preset name, label:preset:key=value,... or "
                          f"{{label:, preset:, set: [...]}}, got {item!r}")
    overrides = item.get("set", [])
    if isinstance(overrides, str):
        overrides = [overrides]
    if not isinstance(overrides, list) or not all(isinstance(o, str) for o in overrides):
        raise ConfigError(f"{where}: variants: {item!r}: set: expected a list of section.key=value")
    preset = str(item["preset"])
    return Variant(str(item.get("label", preset)), preset, tuple(overrides))
