"""Command line: ``windbench [overrides]`` (one run) and ``windbench -m ...`` (a sweep).

Bad input prints one line ``windbench: error: <key>: <what is allowed>`` and exits with
status 2 before anything is written; a run that blows up writes its dataset with
``status = failed`` and exits with status 1 (in a sweep the other runs go on).
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

from windbench.config import register_configs
from windbench.errors import ConfigError
from windbench.sweep import already_done, remove_stale_temporaries, write_status
from windbench.wind.registry import backends, discover

CONFIG_DIR = str(Path(__file__).resolve().parent.parent / "conf")
log = logging.getLogger("windbench")

register_configs()
discover()  # every backend registers its wind/<name>_schema


def _task(cfg: DictConfig) -> str:
    from windbench.simulate import run

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    remove_stale_temporaries(out_dir)
    if cfg.resume and already_done(cfg, out_dir / cfg.output.filename):
        log.info("resume: %s is complete with the same config, skipped", out_dir)
        write_status(out_dir, "skipped")
        return "skipped"
    try:
        result = run(cfg, out_dir)
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


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="config")
def _app(cfg: DictConfig) -> str:
    return _task(cfg)


def main() -> None:
    try:
        preflight(sys.argv[1:])
    except ConfigError as err:
        print(f"windbench: error: {err}", file=sys.stderr)
        sys.exit(2)
    _app()


def preflight(argv: list[str]) -> None:
    """Compose the config of the command line's first run before Hydra starts, so that a
    bad override, a broken config file or a backend without its schema is one line
    (ConfigError) instead of Hydra's report. Sweeps are reduced to their first value."""
    from hydra._internal.utils import get_args_parser

    args = get_args_parser().parse_args(argv)
    if args.help or args.hydra_help or args.cfg or args.info or args.shell_completion:
        return
    if args.config_path or args.config_name or args.config_dir:
        return  # another primary config: Hydra reports on it
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        compose_config(_first_run(args.overrides))
    except (HydraException, OmegaConfBaseException, OSError) as err:
        raise composition_error(err) from err


def _first_run(overrides: list[str]) -> list[str]:
    """``overrides`` with every sweep (``a=1,2``, ``range(...)``) cut to its first value."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import Glob

    out = []
    for override in OverridesParser.create().parse_overrides(overrides):
        if not override.is_sweep_override():
            out.append(override.input_line)
        elif not isinstance(override.value(), Glob):  # a glob needs the option list
            first = next(iter(override.sweep_string_iterator()))
            out.append(f"{override.get_key_element()}={first}")
    return out


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
    return ConfigError(key or "config", message + source)


def compose_config(overrides: list[str] | None = None) -> DictConfig:
    """The resolved config for ``overrides``, without running anything (tests, notebooks)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        return compose(config_name="config", overrides=overrides or [])
