"""One source for every default: the config schema (windbench/config.py and each backend's
schema beside its code). conf/config.yaml and conf/wind/<backend>.yaml may only restate
the schema's defaults (experiments and scenes are where values change), and no code falls
back to a value of its own for a schema key (``x.get("key", value)``,
``getattr(x, "key", value)`` on a config node)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml
from omegaconf import OmegaConf

from windbench.config import WindbenchConfig
from windbench.wind import backends

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"


def flatten(node, prefix: str = "") -> dict[str, object]:
    """Dotted keys of a (nested) mapping -> leaf values; lists are leaves."""
    out = {}
    for key, value in node.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, f"{dotted}."))
        else:
            out[dotted] = value
    return out


def schema_defaults(schema) -> dict[str, object]:
    """The defaults a structured config gives every key (MISSING keys left out)."""
    node = OmegaConf.structured(schema)
    flat = flatten(OmegaConf.to_container(node, resolve=False, throw_on_missing=False))
    return {k: v for k, v in flat.items() if v != "???"}


def yaml_values(path: Path) -> dict[str, object]:
    """A config file's own values: no defaults list, hydra settings or interpolations."""
    raw = yaml.safe_load(path.read_text())
    raw.pop("defaults", None)
    raw.pop("hydra", None)
    flat = flatten(raw)
    return {k: v for k, v in flat.items() if not (isinstance(v, str) and "${" in v)}


def test_config_yaml_restates_the_root_schema():
    defaults = schema_defaults(WindbenchConfig)
    values = yaml_values(CONF / "config.yaml")
    assert values, "config.yaml sets nothing"
    for key, value in values.items():
        assert key in defaults, f"conf/config.yaml sets {key}, which has no schema default"
        assert value == defaults[key], f"conf/config.yaml: {key} = {value}, schema {defaults[key]}"


@pytest.mark.parametrize("path", sorted((CONF / "wind").glob("*.yaml")), ids=lambda p: p.stem)
def test_a_backend_yaml_restates_its_schema(path):
    schema = backends()[path.stem].config
    defaults = schema_defaults(schema)
    for key, value in yaml_values(path).items():
        assert key in defaults, f"{path.name} sets {key}, which {schema.__name__} lacks"
        assert value == defaults[key], f"{path.name}: {key} = {value}, schema {defaults[key]}"


def _schema_leaves() -> dict[str, set]:
    """Leaf key name -> the defaults it has in any schema."""
    leaves: dict[str, set] = {}
    schemas = [WindbenchConfig, *(b.config for b in backends().values())]
    for schema in schemas:
        for key, value in schema_defaults(schema).items():
            if isinstance(value, bool | int | float | str):
                leaves.setdefault(key.rsplit(".", 1)[-1], set()).add(value)
    return leaves


def _config_fallbacks():
    """(file, line, key, literal) of ``node.get("key", literal)`` and
    ``getattr(node, "key", literal)`` where node's source names a config (cfg, params,
    config) and the literal is a number, string or bool."""
    for path in sorted((ROOT / "windbench").rglob("*.py")):
        for call in ast.walk(ast.parse(path.read_text())):
            if not isinstance(call, ast.Call) or len(call.args) < 2:
                continue
            if isinstance(call.func, ast.Attribute) and call.func.attr == "get":
                node, key, default = call.func.value, call.args[0], call.args[1]
            elif isinstance(call.func, ast.Name) and call.func.id == "getattr":
                if len(call.args) < 3:
                    continue
                node, key, default = call.args
            else:
                continue
            source = ast.unparse(node).lower()
            if not any(word in source for word in ("cfg", "params", "config")):
                continue
            if not (isinstance(key, ast.Constant) and isinstance(default, ast.Constant)):
                continue
            if isinstance(default.value, bool | int | float | str):
                leaf = str(key.value).rsplit(".", 1)[-1]
                yield path.relative_to(ROOT), call.lineno, leaf, default.value


def test_no_code_falls_back_to_a_default_of_its_own():
    leaves = _schema_leaves()
    found = list(_config_fallbacks())
    wrong = [
        f"{path}:{line}: {key!r} falls back to {value!r}, schema {sorted(map(repr, leaves[key]))}"
        for path, line, key, value in found
        if key in leaves and value not in leaves[key]
    ]
    assert not wrong, "\n".join(wrong)
