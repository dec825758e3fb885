"""Command line: ``windbench [overrides]`` (one run) and ``windbench -m ...`` (a sweep).

Bad input prints one line ``windbench: error: <key>: <what is allowed>`` and exits with
status 2 before anything is written; a run that blows up writes its dataset with
``status = failed`` and exits with status 1 (in a sweep the other runs go on).
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from windbench.config import register_configs
from windbench.errors import ConfigError
from windbench.sweep import already_done, remove_stale_temporaries, write_status

CONFIG_DIR = str(Path(__file__).resolve().parent.parent / "conf")
log = logging.getLogger("windbench")

register_configs()


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
    _app()


def compose_config(overrides: list[str] | None = None) -> DictConfig:
    """The resolved config for ``overrides``, without running anything (tests, notebooks)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        return compose(config_name="config", overrides=overrides or [])
