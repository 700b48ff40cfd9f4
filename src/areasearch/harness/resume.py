"""A checked evaluation and the state of its results folder: :func:`prepare` turns an
:class:`~areasearch.harness.plan.EvalPlan` into a :class:`RunPlan` without writing anything.

A folder is resumed only with the settings it was made with (``config.json``: the run seed, the
horizon, the realism preset, the world settings and configuration, :func:`areasearch.harness.plan.run_config`), on maps
whose content has not changed since their episodes were played (the SHA-256 of each map's content,
by map id; a folder whose ``config.json`` has no ``maps``, written before maps were pinned, is
resumed and the hashes added when the run next writes episodes there), and with the weights each
method with weights (a ``--policy`` name, a shipped policy) was first evaluated with
(``policies.json``). A method whose episodes there were played with other weights, or with weights
the folder has no record of, is refused, or played again when the plan names it in
:attr:`~areasearch.harness.plan.EvalPlan.replace` (:attr:`RunPlan.replaced`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import NO_REALISM
from ..errors import AreaSearchError, ConfigError
from ..planners import PLANNERS, SHIPPED_POLICIES, shipped_policy
from .episodes import Episode, MapEntry, check_teams, plan_episodes, resolve_maps
from .plan import EvalPlan, check_plan, run_config
from .records import (
    CONFIG_FILE,
    CURVES_FILE,
    EPISODES_FILE,
    POLICIES_FILE,
    REPLACED_FOLDER,
    EpisodeKey,
    episode_key,
    read_curves,
    read_episodes,
    read_record,
)


@dataclass(frozen=True)
class RunPlan:
    """A validated evaluation: what to play and where to write. Built by :func:`prepare`."""

    request: EvalPlan
    """The evaluation as asked for."""
    out: Path
    """The results folder (``~`` expanded)."""
    maps: tuple[MapEntry, ...]
    """The maps of the run, sorted by size class, then id."""
    plan: tuple[Episode, ...]
    """Every episode of the run, in the order rows are written."""
    done: frozenset[EpisodeKey]
    """Keys of planned episodes already in ``episodes.csv``."""
    run_config: dict[str, Any]
    """What ``config.json`` holds, less ``maps`` (:func:`areasearch.harness.plan.run_config`)."""
    policies: tuple[tuple[str, dict[str, str]], ...] = ()
    """``--policy`` methods: name -> weights prefix and SHA-256 (:func:`check_policies`)."""
    maps_record: tuple[tuple[str, str], ...] = ()
    """``config.json``'s ``maps``: the SHA-256 of each map's content by id, those recorded before and this run's."""
    config_current: bool = False
    """``config.json`` already holds :attr:`run_config` and :attr:`maps_record`: a resume writes it only
    when it plays episodes and the map hashes are new."""
    replaced: tuple[str, ...] = ()
    """Methods of :attr:`~areasearch.harness.plan.EvalPlan.replace` whose episodes in :attr:`out` were
    played with other weights, or weights not recorded: set aside before the run plays them again."""


def prepare(request: EvalPlan) -> RunPlan:
    """Check every argument of ``request`` and the output folder without writing anything;
    AreaSearchError (one message) on bad input."""
    check_plan(request)
    out = Path(request.out).expanduser()
    if out.exists() and not out.is_dir():
        raise AreaSearchError(f"{out}: output path is an existing file; give a folder")
    config = run_config(request)
    entries = resolve_maps(request.maps, request.sizes, request.maps_per_size)
    check_teams(entries, request.robots, request.seed, request.config)
    done, maps_record, config_current = _folder_state(out, config, entries)
    checked = {**shipped_weights(request.methods), **check_policies(request.policies, request.methods)}
    replaced = _stale_weights(out, checked, {key[0] for key in done}, request.replace)
    plan = plan_episodes(request, entries)
    return RunPlan(
        request=request,
        out=out,
        maps=tuple(entries),
        plan=tuple(plan),
        done=frozenset(key for key in done & {ep.key for ep in plan} if key[0] not in replaced),
        run_config=config,
        policies=tuple(checked.items()),
        maps_record=tuple(sorted(maps_record.items())),
        config_current=config_current,
        replaced=replaced,
    )


def _folder_state(
    out: Path, config: Mapping[str, Any], entries: Sequence[MapEntry]
) -> tuple[set[EpisodeKey], dict[str, str], bool]:
    """What ``out`` holds already: the keys of its episodes, the maps record to write (those recorded
    merged with ``entries``'), and whether its ``config.json`` holds them already. AreaSearchError
    when the folder was made with other settings or on other maps, or its files are malformed."""
    maps_record = {e.id: e.sha256 for e in entries}
    if not out.is_dir():
        return set(), maps_record, False
    config_current = False
    config_path = out / CONFIG_FILE
    if os.path.lexists(config_path):
        old = read_record(config_path, "results config")
        recorded_maps = _recorded_maps(config_path, old)
        if {k: v for k, v in old.items() if k != "maps"} != config:
            keys = ("format", "seed", "max_steps", "realism", "settings", "config")
            changed = [k for k in keys if old.get(k) != config.get(k)]
            presets = (
                f": realism {old.get('realism', NO_REALISM)} there, {config.get('realism', NO_REALISM)} now"
                if "realism" in changed
                else ""
            )
            raise AreaSearchError(
                f"{out}: holds episodes of a run with other settings ({', '.join(changed)} differ{presets}); "
                "use another --out folder or the same settings"
            )
        _check_maps_unchanged(config_path, recorded_maps, maps_record, entries)
        merged = {**recorded_maps, **maps_record}
        config_current = "maps" in old and merged == recorded_maps
        maps_record = merged
    elif os.path.lexists(out / EPISODES_FILE):
        raise AreaSearchError(f"{out}: has {EPISODES_FILE} but no {CONFIG_FILE}; use another --out folder")
    done = {episode_key(row) for row in read_episodes(out / EPISODES_FILE)}
    read_curves(out / CURVES_FILE)  # a malformed curve file fails now, not after the episodes
    return done, maps_record, config_current


def _stale_weights(
    out: Path, checked: Mapping[str, dict[str, str]], played: set[str], replace: Sequence[str]
) -> tuple[str, ...]:
    """The methods of ``checked`` (name -> the weights they play now) that ``replace`` lists and whose
    episodes in ``out`` were played with other weights, or with weights ``policies.json`` has no record
    of (a method of ``played``, the methods with episodes there, without an entry). AreaSearchError for
    such a method that ``replace`` does not list: a resume would mix the episodes of two policies."""
    if not checked:
        return ()
    path = out / POLICIES_FILE
    recorded = read_record(path, "policies record") if os.path.lexists(path) else {}
    stale = []
    for name, entry in checked.items():
        old = recorded.get(name)
        if old is not None and not isinstance(old, dict):
            raise AreaSearchError(f"{path}: the entry of {name} must be an object with its weights and SHA-256")
        if (old is None and name not in played) or (old is not None and old.get("sha256") == entry["sha256"]):
            continue  # a method new to the folder, or its weights unchanged
        if name in replace:
            stale.append(name)
        elif old is None:
            raise AreaSearchError(
                f"{out}: method {name} has episodes there but no record of the weights that played them (a folder "
                f"written before they were recorded); play them again with --replace {name}, or use another --out "
                "folder"
            )
        else:
            raise AreaSearchError(
                f"{out}: method {name} was evaluated with other weights ({old.get('weights')}, SHA-256 "
                f"{str(old.get('sha256'))[:12]}... there, {entry['sha256'][:12]}... now); play it again with "
                f"--replace {name} (its old episodes move to {out / REPLACED_FOLDER}), or use another --out folder "
                "or another name"
            )
    return tuple(stale)


def shipped_weights(methods: Sequence[str]) -> dict[str, dict[str, str]]:
    """The weights of the shipped policies among ``methods`` (:data:`areasearch.planners.SHIPPED_POLICIES`
    installed): name -> {"weights": ``areasearch/policies/NAME``, "sha256": of its safetensors}, as
    ``policies.json`` records them, so that a folder evaluated before a policy was retrained and shipped
    again is not resumed with the new one."""
    from ..planners.learned import weights_file, weights_sha256

    return {
        name: {"weights": f"areasearch/policies/{name}", "sha256": weights_sha256(shipped_policy(name))}
        for name in methods
        if name in SHIPPED_POLICIES and weights_file(shipped_policy(name)).is_file()
    }


def check_policies(policies: Mapping[str, str], methods: Sequence[str]) -> dict[str, dict[str, str]]:
    """``--policy NAME=PREFIX`` entries checked: NAME a new name listed in ``methods`` (no registered
    planner is shadowed), PREFIX a loadable policy (:func:`areasearch.models.dahgnn.load_policy`, never
    unpickled). Returns name -> {"weights": prefix, "sha256": of its safetensors}."""
    out: dict[str, dict[str, str]] = {}
    for name, prefix in policies.items():
        if not isinstance(name, str) or not name or any(c in name for c in ",= \t\n"):
            raise ConfigError(f"--policy: a method name must be a plain word, got {name!r}")
        if name in PLANNERS:
            raise ConfigError(f"--policy {name}=...: {name!r} is a registered planner; give the policy another name")
        if name not in methods:
            raise ConfigError(f"--policy {name}=...: add {name} to --methods to evaluate it")
        from ..models.weights import load_policy
        from ..planners.learned import weights_sha256

        load_policy(prefix)  # ConfigError naming the file when it is missing or damaged
        out[name] = {"weights": str(prefix), "sha256": weights_sha256(prefix)}
    return out


def _recorded_maps(path: Path, record: Mapping[str, Any]) -> dict[str, str]:
    """The ``maps`` of a results ``config.json`` (map id -> SHA-256 of its content); {} in a folder
    written before maps were pinned. AreaSearchError naming the file when it is malformed."""
    maps = record.get("maps", {})
    if not isinstance(maps, dict) or not all(
        isinstance(k, str) and isinstance(v, str) and len(v) == 64 for k, v in maps.items()
    ):
        raise AreaSearchError(f"{path}: field 'maps' must map each map id to the SHA-256 of its content")
    return dict(maps)


def _check_maps_unchanged(
    path: Path, recorded: Mapping[str, str], current: Mapping[str, str], entries: Sequence[MapEntry]
) -> None:
    """AreaSearchError naming the first map whose content differs from the one its episodes were played on."""
    for entry in entries:
        old = recorded.get(entry.id)
        if old is not None and old != current[entry.id]:
            raise AreaSearchError(
                f"{path}: map {entry.id} has changed since its episodes were played (SHA-256 {old[:12]}... "
                f"recorded, {current[entry.id][:12]}... now in {entry.spec}); a resume would mix episodes of two "
                "maps: use another --out folder, or restore the map"
            )
