"""The viewer's channels: the log's columns grouped into topics, defined once
for the exported MCAP file (``sensaug.export``) and the live view
(``sensaug.live``); ``docs/live.md``.

Every column of the log is in exactly one topic; every message also carries
``tick`` and ``t``. A message is a JSON object, its schema a JSON Schema
generated from the log schema (each field's unit and description), so
Foxglove and PlotJuggler show units without a custom decoder. A float the
log has as NaN ("not known on this side") is JSON ``null``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sensaug import logs

__all__ = ["TOPICS", "Topic", "json_schema", "messages"]


@dataclass(frozen=True)
class Topic:
    """One viewer channel: a topic name, what it shows, its columns."""

    name: str
    title: str
    columns: tuple[str, ...]

    @property
    def schema_name(self) -> str:
        return "sensaug." + self.name.strip("/")


#: The viewer's channels, in the order a viewer lists them.
TOPICS: tuple[Topic, ...] = (
    Topic("/handle", "handle position and velocity, the measurement the controller received",
          ("x", "xdot", "x_meas", "xdot_meas", "fresh")),
    Topic("/targets", "the robot's and the partner's targets and the tracking error",
          ("tau", "tau_h", "e", "e_meas")),
    Topic("/phase", "the protocol's phase (-1: the controlled stop)", ("phase", "ramp")),
    Topic("/partner_gains", "the robot's estimates of the partner's LQR gains and their variances",
          ("Lhx_hat", "Lhv_hat", "Lhh_hat", "Lhx_var", "Lhv_var", "Lhh_var")),
    Topic("/partner_target", "the robot's estimate of the partner's target", ("tau_h_hat", "tau_h_var")),
    Topic("/partner_delay", "the partner's sensorimotor delays stages 1-2 assume (ms) and the search's margin",
          ("partner_delay_visual_ms", "partner_delay_proprioceptive_ms", "partner_delay_margin_nats")),
    Topic("/goal_integration", "stage 3: (x - tau) estimated from own sensing and fused with the partner channel",
          ("e_hat_own", "e_hat_fused", "e_hat_own_var", "e_hat_fused_var", "partner_var")),
    Topic("/torque", "commanded torque (model units), the partner's, motor noise, torque sent to the drive, "
          "its friction compensation", ("u", "u_h", "eps", "torque_nm", "friction_nm")),
    Topic("/safety", "drive state, the torque guard's outcome, feedback age",
          ("drive_state", "guard", "feedback_age_ticks")),
    Topic("/loop", "loop timing: wake-up and sleep latency, compute",
          ("wake_latency_us", "sleep_latency_us", "compute_us")),
    Topic("/mirror", "simulation section: the partner's estimates of the robot",
          ("Lx_hat", "Lv_hat", "Lh_hat", "Lx_var", "Lv_var", "Lh_var", "tau_hat", "tau_hat_var",
           "e_h_meas", "e_h_hat_own", "e_h_hat_fused")),
)

_KINDS = {"int": "integer", "float": ["number", "null"], "bool": "boolean"}
_COLUMN_INFO = {c[0]: c for c in logs._SCHEMA["columns"]}


def _field(name: str, units: dict[str, str] | None = None) -> dict:
    _, unit, kind, description = _COLUMN_INFO[name]
    unit = (units or {}).get(name, unit)
    return {"type": _KINDS[kind], "description": f"{description} [{unit}]", "unit": unit}


def json_schema(topic: Topic, extra: dict[str, dict] | None = None, units: dict[str, str] | None = None) -> dict:
    """The JSON Schema of a topic's messages (``tick``, ``t`` and its columns,
    each with its unit: from ``units`` when given, e.g. a log's physical
    :attr:`~sensaug.Log.units`, else the log schema's symbols), plus
    ``extra`` properties."""
    props = {name: _field(name, units) for name in ("tick", "t", *topic.columns)}
    props.update(extra or {})
    return {"title": topic.schema_name, "description": topic.title, "type": "object", "properties": props}


def _json_texts(column: np.ndarray) -> list[str]:
    """Each value of a column as JSON text: floats in their shortest
    round-trip form (``repr``, as ``json.dumps``), NaN and infinities as
    ``null``."""
    kind = column.dtype.kind
    if kind == "b":
        return ["true" if v else "false" for v in column.tolist()]
    if kind in "iu":
        return list(map(str, column.tolist()))
    texts = list(map(repr, column.tolist()))
    return [t if t[-1].isdigit() else "null" for t in texts]  # 'nan', 'inf', '-inf' end in a letter


def messages(data: np.ndarray, topic: Topic) -> list[bytes]:
    """Every row's message on a topic, JSON-encoded: the same values as
    :func:`message`, built column-wise (a 40 000-tick log has 400 000
    messages)."""
    names = ("tick", "t", *topic.columns)
    template = "{" + ",".join(f'"{name}":%s' for name in names) + "}"
    return [(template % values).encode() for values in zip(*(_json_texts(data[name]) for name in names))]
