"""Secrets (API keys, SMTP and operator passwords): from the environment or a key file.

A key file holds ``NAME=value`` lines or a JSON object (the seed's ``api_keys.json``).
It must be readable by its owner only (mode 600): a file others can read is refused,
with the ``chmod`` that fixes it. Values are returned as :class:`SecretStr`, which
prints as ``**********`` and so never lands in a log.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

from pydantic import SecretStr

from sage_robot.core.errors import ConfigError


def _read_key_file(path: Path) -> dict[str, str]:
    try:
        st = path.stat()
    except FileNotFoundError:
        raise ConfigError(f"{path}: key file not found") from None
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(f"{path}: key file is readable by others; fix it with: chmod 600 {path}")
    text = path.read_text(encoding="utf-8")
    if text.lstrip().startswith("{"):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path}: not valid JSON (line {exc.lineno}): {exc.msg}") from None
        return {str(k): str(v) for k, v in data.items()}
    out: dict[str, str] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if "=" not in line:
            raise ConfigError(f"{path}: line {n}: expected NAME=value")
        k, v = line.split("=", 1)
        out[k.strip()] = v.strip().strip('"').strip("'")
    return out


def read_secret(name: str, key_file: str | Path | None = None) -> SecretStr | None:
    """The secret ``name`` from the environment, else the key file, else None."""
    value = os.environ.get(name)
    if value:
        return SecretStr(value)
    if key_file:
        found = _read_key_file(Path(key_file)).get(name)
        if found:
            return SecretStr(found)
    return None
