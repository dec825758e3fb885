"""Command line: ``windbench [overrides]`` (one run) and ``windbench -m ...`` (a sweep).

Bad input prints one line ``windbench: error: <key>: <what is allowed>`` and exits with
status 2 before anything is written; so does a run folder another live run holds. A run
that blows up writes its dataset with ``status = failed`` and exits with status 1. A sweep
exits 0 when every run is complete or skipped, 2 when any was invalid, else 1 when any
failed (:func:`windbench.sweep.exit_status`); the other runs go on either way.
"""

from __future__ import annotations

import logging
import re
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from windbench import sweep
from windbench.config import config_dir, register_configs
from windbench.errors import ConfigError, FolderBusy
from windbench.sweep import FolderLock, resume_decision, write_status
from windbench.wind.registry import backends, discover

CONFIG_DIR = str(config_dir())
log = logging.getLogger("windbench")

register_configs()
discover()  # every backend registers its wind/<name>_schema


def _task(cfg: DictConfig) -> str:
    from windbench.simulate import run

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    try:
        with FolderLock(out_dir, "run folder"):
            return _run_in(cfg, out_dir, multirun, run)
    except FolderBusy as err:  # another live run writes there: touch nothing
        print(f"windbench: error: {err}", file=sys.stderr)
        if multirun:
            return "busy"
        sys.exit(2)


def _run_in(cfg: DictConfig, out_dir: Path, multirun: bool, run) -> str:
    if cfg.resume.enabled:
        skip, why = resume_decision(cfg, out_dir / cfg.output.filename)
        log.info("resume: %s %s: %s", out_dir, "skipped" if skip else "runs", why)
        if skip:
            write_status(out_dir, "skipped")
            return "skipped"
    try:
        result = run(cfg, out_dir, jobs=parallel_jobs() if multirun else 1)
    except ConfigError as err:
        print(f"windbench: error: {err}", file=sys.stderr)
        write_status(out_dir, "invalid", reason=str(err))
        if multirun:
            return "invalid"
        sys.exit(2)
    write_status(out_dir, result.status, failure=result.failure)
    if result.status == "failed":
        print(f"windbench: run failed: {result.failure} (dataset: {result.path})", file=sys.stderr)
        if not multirun:
            sys.exit(1)
    else:
        log.info("wrote %s", result.path)
    return result.status


def parallel_jobs() -> int:
    """Runs the sweep's launcher has in flight at once: joblib's ``n_jobs`` (negative n:
    the available cores + 1 + n, as joblib counts), 1 for the launchers that run one job
    per process or machine (basic, submitit)."""
    from omegaconf import OmegaConf

    from windbench.runtime import available_cores

    n = OmegaConf.select(HydraConfig.get(), "launcher.n_jobs", default=None)
    if n is None:
        return 1
    n = int(n)
    return max(1, available_cores() + 1 + n if n < 0 else n)


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="config")
def _app(cfg: DictConfig) -> str:
    return _task(cfg)


def main() -> None:
    argv = shorthand(sys.argv[1:])
    if _wants_help(argv):
        from windbench.help import help_text

        try:
            print(help_text([a for a in argv if not a.startswith("-")]))
        except ConfigError as err:
            _refuse(err)
        return
    try:
        target = preflight(argv)
    except ConfigError as err:
        _refuse(err)
    if target is None:  # --cfg, --info, ...: Hydra answers
        sys.argv = [sys.argv[0], *argv]
        _app()
        return
    folder, where = target
    pinned = [a for a in argv if not a.startswith(f"{where}=")]
    sys.argv = [sys.argv[0], *pinned, f"{where}={_quoted(str(folder))}"]  # the locked folder
    try:
        with FolderLock(folder, where):
            _app()
    except FolderBusy as err:
        _refuse(err)
    sys.exit(sweep.exit_code)


def _refuse(err: Exception) -> None:
    print(f"windbench: error: {err}", file=sys.stderr)
    sys.exit(2)


def _wants_help(argv: list[str]) -> bool:
    return any(a in ("--help", "-h") for a in argv)


def _quoted(value: str) -> str:
    """A Hydra override value that is exactly ``value`` (quoted, escaped)."""
    return "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"


def shorthand(argv: list[str]) -> list[str]:
    """``resume=VALUE`` -> ``resume.enabled=VALUE`` (``resume`` became a group of keys:
    ``resume.enabled``, ``resume.code``)."""
    return [re.sub(r"^resume=", "resume.enabled=", a) for a in argv]


def preflight(argv: list[str]) -> tuple[Path, str] | None:
    """Compose the config of the command line's first run before Hydra starts, so that a
    bad override, a broken config file or a backend without its schema is one line
    (ConfigError) instead of Hydra's report. Sweeps are reduced to their first value.

    Returns the folder the run (or the sweep) will write and its key (``hydra.run.dir`` or
    ``hydra.sweep.dir``) with every ``${now:...}`` resolved, or None when Hydra is only
    asked about itself (``--cfg``, ``--info``, another config).
    """
    from hydra._internal.utils import get_args_parser

    args = get_args_parser().parse_args(argv)
    if args.help or args.hydra_help or args.cfg or args.info or args.shell_completion:
        return None
    if args.config_path or args.config_name or args.config_dir:
        return None  # another primary config: Hydra reports on it
    overrides = [shorthand([o])[0] for o in args.overrides]
    cfg = checked_compose(overrides)
    multirun = bool(args.multirun) or str(cfg.hydra.mode) == "MULTIRUN"
    where = "hydra.sweep.dir" if multirun else "hydra.run.dir"
    return Path(cfg.hydra.sweep.dir if multirun else cfg.hydra.run.dir), where


def checked_compose(overrides: list[str]) -> DictConfig:
    """The first run's config with Hydra's node (ConfigError for any fault, one line)."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException
    from yaml import YAMLError

    first = _first_run(overrides)
    _refuse_new_keys(first)
    try:
        return compose_config(first, hydra_node=True)
    except YAMLError as err:
        raise yaml_error(err) from err
    except (HydraException, OmegaConfBaseException, OSError) as err:
        cause = err.__cause__ or err.__context__
        if isinstance(cause, YAMLError):
            raise yaml_error(cause) from err
        raise composition_error(err) from err


def _first_run(overrides: list[str]) -> list[str]:
    """``overrides`` with every sweep (``a=1,2``, ``range(...)``) cut to its first value;
    an override that does not parse is a ConfigError naming it."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import Glob
    from hydra.errors import OverrideParseException

    parser = OverridesParser.create()
    out = []
    for text in overrides:
        try:
            (override,) = parser.parse_overrides([text])
        except OverrideParseException as err:
            key = text.split("=", 1)[0].lstrip("+~") or text
            what = str(err).splitlines()[0].strip()
            raise ConfigError(
                key, f"cannot parse the override {text!r} ({what}); the form is key=value"
            ) from None
        if not override.is_sweep_override():
            out.append(override.input_line)
        elif not isinstance(override.value(), Glob):  # a glob needs the option list
            first = next(iter(override.sweep_string_iterator()))
            out.append(f"{override.get_key_element()}={first}")
    return out


def _refuse_new_keys(overrides: list[str]) -> None:
    """``+key=value`` adds a key the schema does not have: refused (outside ``hydra``)."""
    for text in overrides:
        if text.startswith("+"):
            key = text.lstrip("+").split("=", 1)[0]
            if not key.startswith("hydra"):
                raise ConfigError(
                    key,
                    f"unknown key: {text.split('=', 1)[0]} would add it, and windbench takes "
                    "only the keys of its schema; set an existing key without '+' "
                    "(windbench --help lists them)",
                )


def yaml_error(err) -> ConfigError:
    """A YAML parse error as ``<file>: line N, column M: <what>``."""
    mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
    what = getattr(err, "problem", None) or str(err).splitlines()[0]
    if mark is None:
        return ConfigError("config file", f"is not valid YAML: {what}")
    name = mark.name if mark.name and not mark.name.startswith("<") else "a config file"
    return ConfigError(
        name, f"line {mark.line + 1}, column {mark.column + 1}: not valid YAML: {what}"
    )


CONVERSIONS = {"Float": "a number", "Integer": "an integer", "Boolean": "true or false"}


def composition_error(err: Exception) -> ConfigError:
    """One ConfigError for a Hydra composition failure: the key or file and what is wrong."""
    from hydra.errors import MissingConfigException

    text = str(err)
    missing = re.search(r"Could not load '(\w+)/(\w+)_schema'", text)
    if isinstance(err, MissingConfigException) and missing:
        group, name = missing.groups()
        return ConfigError(
            group,
            f"the config file {group}/{name}.yaml names the schema '{name}_schema', but no "
            f"backend '{name}' is registered: decorate its class with "
            f"@register_backend('{name}', config=<schema>) in the backend's module "
            f"(registered: {sorted(backends())})",
        )
    where = re.match(r"In '([\w/]+)'", text)
    source = f" (in {where.group(1)}.yaml)" if where and where.group(1) != "config" else ""
    unknown = re.search(r"Could not find '(\w+)/([^']+)'", text)
    if unknown:
        group, name = unknown.groups()
        options = re.findall(r"^\t(\w+)$", text, flags=re.MULTILINE)
        allowed = [o for o in options if not o.endswith("_schema")]
        return ConfigError(group, f"no config {name!r}; allowed {allowed}")
    lines = []
    for part in (str(err.__cause__ or ""), text):
        lines += [ln.strip() for ln in part.splitlines() if ln.strip()]
    lines = [ln for ln in lines if not re.match(r"In '[\w/]+': \w+ raised while", ln)]
    key = next((ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("full_key:")), "")
    message = lines[0] if lines else type(err).__name__
    conversion = re.match(r"Value '(.*)' of type '\w+' could not be converted to (\w+)", message)
    boolean = re.match(r"Value '(.*)' is not a valid bool", message)
    if conversion and conversion.group(2) in CONVERSIONS:
        message = f"must be {CONVERSIONS[conversion.group(2)]}, got {conversion.group(1)!r}"
    elif boolean:
        message = f"must be true or false, got {boolean.group(1)!r}"
    elif message.startswith("Key '") and " not in '" in message:
        message += _allowed_keys(err)
    return ConfigError(key or "config", message + source)


def _allowed_keys(err: Exception) -> str:
    """``; allowed [...]``: the keys of the structured config an unknown key was set in."""
    import dataclasses

    for exc in (err, err.__cause__):
        kind = getattr(exc, "object_type", None)
        if isinstance(kind, type) and dataclasses.is_dataclass(kind):
            return f"; allowed {[f.name for f in dataclasses.fields(kind)]}"
    return ""


def compose_config(overrides: list[str] | None = None, hydra_node: bool = False) -> DictConfig:
    """The resolved config for ``overrides``, without running anything (tests, notebooks);
    ``hydra_node`` keeps Hydra's own settings (run and sweep folders)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        return compose(
            config_name="config",
            overrides=shorthand(overrides or []),
            return_hydra_config=hydra_node,
        )
