"""sha256 of the logs of the preset trials: every row (the packed records of
``Trial.data``), the configuration recorded in the metadata, the resolved
gains and the run's summary. Printed one preset per line; with ``--check
FILE`` compared against digests printed before (exit 1 on any difference).

Behaviour-preserving refactors state these before and after
(``python scripts/preset_digests.py > before.txt``, then ``--check before.txt``).
A change that adds a log column or a configuration table, and nothing else,
is checked against digests from before it with ``--drop-column NAME`` and
``--drop-config DOTTED.KEY`` (each repeatable): the digests are then of the
rows without that column (packed as before) and of the recorded
configuration without that key.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path
from typing import Sequence

from numpy.lib.recfunctions import drop_fields, repack_fields

from sensaug import ScenarioConfig, presets, run

REPO = Path(__file__).resolve().parent.parent

PRESETS = {
    "hi5_experiment": presets.hi5_experiment,
    "hi5_experiment_lhh0_no_integration": lambda: presets.hi5_experiment(0.0, integrate=False, seed=3),
    "hi5_rig": presets.hi5_rig,
    "simulation_section": presets.simulation_section,
    "simulation_integration": presets.simulation_integration,
    "simulation_integration_off": lambda: presets.simulation_integration(integrate=False, seed=1),
    "configs/hi5_rig.toml": lambda: ScenarioConfig.from_toml(REPO / "configs/hi5_rig.toml"),
    "configs/hi5_vcan.toml": lambda: ScenarioConfig.from_toml(REPO / "configs/hi5_vcan.toml"),
}


def without_key(config: dict, dotted: str) -> dict:
    """``config`` without the (nested) key ``dotted``, e.g. ``rig.friction``."""
    head, _, rest = dotted.partition(".")
    if head not in config:
        return config
    if not rest:
        return {k: v for k, v in config.items() if k != head}
    return {**config, head: without_key(config[head], rest)}


def digest(name: str, drop_columns: Sequence[str] = (), drop_config: Sequence[str] = ()) -> str:
    trial = run(PRESETS[name]())
    rows = repack_fields(drop_fields(trial.data, list(drop_columns), usemask=False, asrecarray=False))
    config = trial.meta["config"]
    for key in drop_config:
        config = without_key(config, key)
    h = hashlib.sha256()
    h.update(rows.tobytes())
    h.update(json.dumps(config, sort_keys=True).encode())
    h.update(json.dumps(trial.meta["resolved"]["robot"], sort_keys=True).encode())
    h.update(json.dumps(trial.meta["resolved"]["partner"], sort_keys=True).encode())
    h.update(json.dumps(trial.summary, sort_keys=True).encode())
    return h.hexdigest()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--check", type=Path, help="digests printed before; exit 1 on a difference")
    parser.add_argument("--drop-column", action="append", default=[], metavar="NAME",
                        help="a log column added since the digests compared with (repeatable)")
    parser.add_argument("--drop-config", action="append", default=[], metavar="DOTTED.KEY",
                        help="a configuration key added since then, e.g. rig.friction (repeatable)")
    args = parser.parse_args()
    now = {name: digest(name, args.drop_column, args.drop_config) for name in PRESETS}
    for name, d in now.items():
        print(f"{d}  {name}")
    if args.check is None:
        return 0
    before = dict(reversed(line.split(maxsplit=1)) for line in args.check.read_text().splitlines())
    bad = [n for n in PRESETS if before.get(n) != now[n]]
    for n in bad:
        print(f"DIFFERS: {n}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
