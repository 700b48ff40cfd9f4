"""Policy files of the DA-HGNN network: ``<prefix>.safetensors`` (the weights, never a pickle) beside
``<prefix>.json`` (the format's name and version, the network config, every tensor's name and shape).
:func:`save_policy` writes them, :func:`load_policy` checks and reads them before anything is allocated.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch

from ..errors import ConfigError
from .network import DAHGNN, network_shapes
from .network_config import NetworkConfig, config_from_dict, config_to_dict, short_repr

FORMAT = "areasearch.dahgnn"  # the policy file format's name (not a module path): every policy JSON carries it
"""``format`` entry of a saved policy's JSON file."""
FORMAT_VERSION = 2
"""Version 2 added ``norm`` and ``score_scale`` to the config; a version-1 file is read with
``norm = "none"`` (the architecture it was trained with)."""


def save_policy(path_prefix: str | Path, model: DAHGNN, config: NetworkConfig | None = None) -> tuple[Path, Path]:
    """Write ``<prefix>.safetensors`` (the weights) and ``<prefix>.json`` (format, config, tensor
    names and shapes). Returns both paths."""
    from safetensors.torch import save_file

    cfg = config or model.config
    if cfg != model.config:
        raise ConfigError("save_policy: the config differs from the model's")
    prefix = Path(path_prefix)
    weights, meta = prefix.with_name(prefix.name + ".safetensors"), prefix.with_name(prefix.name + ".json")
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in model.state_dict().items()}
    save_file(tensors, str(weights), metadata={"format": FORMAT})
    doc = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "config": config_to_dict(cfg),
        "tensors": {k: list(v.shape) for k, v in tensors.items()},
    }
    meta.write_text(json.dumps(doc, indent=1) + "\n")
    return weights, meta


MAX_POLICY_JSON_BYTES = 4 * 2**20
"""Largest policy JSON read, bytes (a six-round network's file lists its 2,245 tensors in ~110 KB)."""


def load_policy(path_prefix: str | Path, device: torch.device | str = "cpu") -> tuple[DAHGNN, NetworkConfig]:
    """Read what :func:`save_policy` wrote (never unpickles) and return (model in eval mode, config).
    Raises ConfigError, naming the file and what is wrong, for a missing, truncated or corrupted
    file, an unknown config, or tensors whose names or shapes do not match the config.

    Nothing is allocated before the files are checked: the JSON is read up to
    :data:`MAX_POLICY_JSON_BYTES` and its config validated (every size and count bounded,
    :data:`~areasearch.models.network_config.NETWORK_SIZES`); the network's tensor shapes are found on
    the meta device (:func:`~areasearch.models.network.network_shapes`, at most
    :data:`~areasearch.models.network_config.MAX_PARAMETERS`) and compared with the JSON's tensor list
    and the safetensors file's own header; only then is the network built and the weights read."""
    from safetensors import SafetensorError, safe_open
    from safetensors.torch import load_file

    from ..inputs import check_path, parse_json, read_bytes

    prefix = check_path(path_prefix, "policy weights", ConfigError)
    weights, meta = prefix.with_name(prefix.name + ".safetensors"), prefix.with_name(prefix.name + ".json")
    if not os.path.lexists(meta):
        raise ConfigError(f"{meta}: cannot read the policy config: no such file")
    data_bytes = read_bytes(meta, "policy config", MAX_POLICY_JSON_BYTES, None, ConfigError)
    doc = parse_json(data_bytes, f"{meta}: cannot read the policy config", ConfigError)
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ConfigError(f"{meta}: not a DA-HGNN policy file (format must be {FORMAT!r})")
    version = doc.get("version")
    if version not in (1, FORMAT_VERSION) or isinstance(version, bool):
        raise ConfigError(f"{meta}: format version {short_repr(version)}, this areasearch reads 1 and {FORMAT_VERSION}")
    data = doc.get("config")
    if version == 1 and isinstance(data, dict):
        if "norm" in data or "score_scale" in data:
            raise ConfigError(f"{meta}: a version-1 policy config cannot name norm or score_scale")
        data = {**data, "norm": "none"}  # version 1: the unnormalised rounds it was trained with
    config = config_from_dict(data, str(meta))
    expected = network_shapes(config, str(meta))
    listed = doc.get("tensors")
    if listed != expected:
        raise ConfigError(f"{meta}: tensor list does not match the config: {_mismatch(expected, listed)}")
    try:
        with safe_open(str(weights), framework="pt", device="cpu") as header:  # reads the header only
            found = {k: list(header.get_slice(k).get_shape()) for k in header.keys()}
            dtypes = {k: header.get_slice(k).get_dtype() for k in header.keys()}
    except (OSError, SafetensorError, ValueError, RuntimeError) as error:
        raise ConfigError(f"{weights}: cannot read the weights (truncated or not safetensors): {error}") from None
    if found != expected:
        raise ConfigError(f"{weights}: tensors do not match {meta.name}: {_mismatch(expected, found)}")
    for name, dtype in dtypes.items():
        if dtype != "F32":
            raise ConfigError(f"{weights}: tensor {name!r} has dtype {dtype}, expected float32")
    try:
        tensors = load_file(str(weights), device="cpu")
    except (OSError, SafetensorError, ValueError, RuntimeError) as error:
        raise ConfigError(f"{weights}: cannot read the weights (truncated or not safetensors): {error}") from None
    model = DAHGNN(config)
    for name, tensor in tensors.items():
        if tensor.dtype != model.state_dict()[name].dtype:
            raise ConfigError(f"{weights}: tensor {name!r} has dtype {tensor.dtype}, expected float32")
        if not torch.isfinite(tensor).all():
            raise ConfigError(f"{weights}: tensor {name!r} holds NaN or infinite values")
    model.load_state_dict(tensors, strict=True)
    return model.to(device).eval(), config


def _mismatch(expected: dict[str, list[int]], found: object) -> str:
    if not isinstance(found, dict):
        return "no tensor list"
    missing = sorted(set(expected) - set(found))
    extra = sorted(set(found) - set(expected))
    shapes = [f"{k} {found[k]} != {expected[k]}" for k in sorted(set(expected) & set(found)) if found[k] != expected[k]]
    parts = []
    if missing:
        parts.append(f"missing {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}")
    if extra:
        parts.append(f"unexpected {', '.join(extra[:5])}{' ...' if len(extra) > 5 else ''}")
    if shapes:
        parts.append(f"shape {'; '.join(shapes[:5])}{' ...' if len(shapes) > 5 else ''}")
    return "; ".join(parts) or "different"
