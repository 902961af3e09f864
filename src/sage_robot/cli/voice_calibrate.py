"""`sage voice wake calibrate`: a wake model's threshold and patience from recordings,
written to the profile given with ``--profile`` (see :mod:`sage_robot.voice.calibrate`)."""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path
from typing import Any

from sage_robot.core.errors import ConfigError


def _model(args: argparse.Namespace, vs: Any) -> str:
    models = args.model or list(vs.wake_models)
    if len(models) != 1:
        raise ConfigError(f"calibrate one model at a time: give --model (the profile has {models})")
    return str(models[0])


def write_profile(path: Path, updates: dict[str, Any]) -> None:
    """Merge ``updates`` into the file's ``voice:`` section; the result must load.
    (Comments in the file are not kept: the YAML is written back whole.)"""
    import yaml

    from sage_robot.core.config.loader import parse_profile

    data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    if not isinstance(data, dict) or not isinstance(data.get("voice", {}), dict):
        raise ConfigError(f"{path}: expected a mapping with a voice: section")
    data["voice"] = {**data.get("voice", {}), **updates}
    text = yaml.safe_dump(data, sort_keys=False)
    parse_profile(text, str(path))  # validates before anything is written
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    os.replace(tmp, path)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from sage_robot.core.config import load_profile
    from sage_robot.voice.calibrate import (
        DEFAULT_MAX_FA_PER_HOUR,
        THRESHOLDS,
        audio_files,
        calibrate_files,
        profile_update,
    )
    from sage_robot.voice.wake import OpenWakeWordEngine, resolve_wake_model

    if not args.positives or not args.negatives:
        raise ConfigError("calibrate needs --positives DIR and --negatives DIR")
    vs = load_profile(args.profile).voice
    spec = _model(args, vs)
    limit = DEFAULT_MAX_FA_PER_HOUR if args.max_fa_per_hour is None else args.max_fa_per_hour
    if limit < 0:
        raise ConfigError(f"--max-fa-per-hour must be >= 0, got {limit}")
    positives = audio_files(args.positives, "--positives")
    negatives = audio_files(args.negatives, "--negatives")
    name, _ = resolve_wake_model(spec)
    engine = OpenWakeWordEngine([spec])
    smoothing = vs.wake_model_smoothing.get(name, 1 if name in engine.custom_names
                                            else vs.wake_smoothing_frames)  # fmt: skip
    cal = calibrate_files(engine, name, positives, negatives, smoothing, vs.wake_refractory_s, limit)
    updates = profile_update(vs, cal)
    written = None
    if args.profile and not args.dry_run:
        write_profile(Path(args.profile), updates)
        written = args.profile
    if args.json:
        print(json.dumps({**cal.as_dict(), "profile": written, "voice": updates}))
        return 0
    print(f"{name}: threshold {cal.threshold:.2f} (same results from {cal.band[0]:.2f} to "
          f"{cal.band[1]:.2f}), patience {cal.patience} frame(s), smoothing {cal.smoothing}")
    print(f"  false rejects {cal.false_rejects}/{cal.positives} ({cal.false_reject_rate:.1%}); "
          f"false accepts {cal.false_accepts} in {cal.negative_hours * 60:.1f} min of negatives "
          f"({cal.false_accepts_per_hour:.2f}/h, target <= {cal.max_fa_per_hour:g}/h"
          f"{'' if cal.meets_target else ': NOT MET'})")
    print(f"  best negative score {cal.negatives_best:.3f}, weakest positive {cal.positives_worst:.3f}")
    if cal.band[0] <= THRESHOLDS[0]:
        print("  warning: no negative came near the model's score: record more (and harder) "
              "negatives for a threshold the negatives bound")  # fmt: skip
    if written:
        print(f"wrote voice.wake_model_thresholds/patience[{name}] to {written}")
    else:
        print("not written (give --profile FILE to write it); the profile's voice: keys would be:")
        print(json.dumps(updates))
    if name not in {resolve_wake_model(m)[0] for m in vs.wake_models}:
        print(f"note: {name} is not in the profile's voice.wake_models yet (add {spec})")
    return 0
