"""``windbench --help [overrides]``: the config groups with their options, the main keys with
their values, units and allowed values (from the schema, :func:`windbench.config.setting`),
and the keys of the chosen wind backend with the comments of its config file.
"""

from __future__ import annotations

import re
from pathlib import Path

from omegaconf import OmegaConf

from windbench.config import allowed, schema_fields

GROUPS = ("wind", "scene", "experiment")
USAGE = """\
windbench: the wind models of Keckeisen et al. (WSCG 2004) on cloth, one run per config.

usage: windbench [KEY=VALUE ...]              one run (dataset: <run folder>/windbench.nc)
       windbench -m KEY=A,B [KEY=VALUE ...]   a sweep (Hydra multirun)
       windbench --help [KEY=VALUE ...]       this page for that config (e.g. wind=particles)
       windbench --hydra-help                 Hydra's own flags (--cfg job, --info, ...)
       windbench-report DIR...                the report of run or sweep folders

exit status: 0 done; 1 a run failed (its dataset says why); 2 bad input (one line naming the
key) or the run folder is in use. A sweep: 0 when every run is complete or skipped, 2 when
any was invalid, else 1 when any failed."""


def options(config_dir: Path, group: str) -> list[str]:
    """The options of a config group: its YAML files (schemas are not options)."""
    return sorted(p.stem for p in (config_dir / group).glob("*.yaml"))


def yaml_comments(path: Path) -> dict[str, str]:
    """``key: value  # comment`` lines of a config file -> {key: comment}."""
    out = {}
    if path.is_file():
        for line in path.read_text().splitlines():
            m = re.match(r"^(\w+):[^#]*#\s*(.+)$", line)
            if m:
                out[m.group(1)] = m.group(2).strip()
    return out


def _table(rows: list[tuple[str, str, str]]) -> list[str]:
    width = [max((len(r[i]) for r in rows), default=0) for i in range(2)]
    return [f"  {k:<{width[0]}}  {v:<{width[1]}}  {d}".rstrip() for k, v, d in rows]


def _value(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, bool):
        return str(v).lower()
    return "null" if v is None else str(v)


def help_text(overrides: list[str]) -> str:
    """The help page for the config ``overrides`` compose to (ConfigError if they do not)."""
    from windbench.cli import CONFIG_DIR, checked_compose

    config_dir = Path(CONFIG_DIR)
    cfg = checked_compose(overrides)
    lines = [USAGE, "", "config groups (GROUP=OPTION; * marks this config's choice):"]
    chosen = {g: OmegaConf.select(cfg, f"hydra.runtime.choices.{g}") for g in GROUPS}
    rows = []
    for group in GROUPS:
        opts = [f"{o}*" if o == chosen[group] else o for o in options(config_dir, group)]
        rows.append((group, ", ".join(opts), ""))
    lines += _table(rows)
    lines += ["", "main keys (value, units; allowed values):"]
    rows = []
    for key, f in schema_fields():
        meta = f.metadata
        units = meta["units"] if meta["units"] not in ("", "1") else ""
        value = f"{_value(OmegaConf.select(cfg, key))} {units}".strip()
        rule = allowed(meta)
        rows.append((key, value, meta["doc"] + (f" ({rule})" if rule else "")))
    lines += _table(rows)
    wind = cfg.wind.name
    comments = yaml_comments(config_dir / "wind" / f"{wind}.yaml")
    lines += ["", f"wind={wind} keys (value; comment of conf/wind/{wind}.yaml):"]
    rows = [
        (f"wind.{k}", _value(v), comments.get(k, ""))
        for k, v in OmegaConf.to_container(cfg.wind, resolve=True).items()
    ]
    lines += _table(rows)
    lines += [
        "",
        "scene.* keys: see the scene files (conf/scene/*.yaml) and DESIGN.md 'Scene config'.",
        f"Config files: {config_dir}",
        f"More: {_readme()} (Running; Exit status; Resume; the run dataset).",
    ]
    return "\n".join(lines)


def _readme() -> str:
    readme = Path(__file__).resolve().parent.parent / "README.md"
    return str(readme) if readme.is_file() else "README.md of the windbench source"
