"""Where cinetransfer keeps caches: the one place that reads $CT_CACHE_DIR."""
from __future__ import annotations

import os
from pathlib import Path

from cinetransfer.shared.errors import ConfigError

ENV_CACHE = "CT_CACHE_DIR"


def cache_dir(*parts: str) -> Path:
    """$CT_CACHE_DIR, else $XDG_CACHE_HOME/cinetransfer, else ~/.cache/cinetransfer; `parts` appended."""
    env = os.environ.get(ENV_CACHE)
    if env:
        base = Path(env)
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "cinetransfer"
    return base.joinpath(*parts)


def named_yaml(name_or_path: str, shipped_dir: Path) -> tuple[Path, bool]:
    """(the file meant, whether it was given as a path): a .yaml/.yml name or an existing path as
    given, else the shipped `shipped_dir/NAME.yaml`. The caller says what is wrong if it is not a file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p, True
    return shipped_dir / f"{name_or_path}.yaml", False


def shipped_names(shipped_dir: Path) -> list[str]:
    return sorted(p.stem for p in shipped_dir.glob("*.yaml"))


def resolve_named_yaml(name_or_path: str, shipped_dir: Path, *, missing: str, unknown: str) -> Path:
    """The YAML file `name_or_path` means (see named_yaml). Raises ConfigError with `missing` (a
    path given that is not a file) or `unknown` (a name not shipped), formatted with {path},
    {name} and {shipped}."""
    p, as_path = named_yaml(name_or_path, shipped_dir)
    if p.is_file():
        return p
    msg = missing if as_path else unknown
    raise ConfigError(msg.format(path=p, name=repr(name_or_path), shipped=", ".join(shipped_names(shipped_dir))))
