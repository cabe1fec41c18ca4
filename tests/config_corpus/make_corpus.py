"""Writes the configuration corpus: malformed and edge-case files, each with
the field its first error must name (or "valid"), in EXPECTED.json.

tests/test_config_corpus.py runs every file through `python -m sensaug check`
and `sensaug-rt --check` and asserts identical verdicts and messages, and that
the message names the expected field. Run this script to regenerate the files
after changing the cases below.
"""

from __future__ import annotations

import json
from pathlib import Path

HERE = Path(__file__).resolve().parent

PHASE = """[[phases]]
kind = "{kind}"
duration_s = {duration}
robot_target = [{{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }}]
partner_target = [{{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }}]
target_noise_std = {noise}
"""


def phases(*kinds: str, duration: str = "2.0", noise: str = "0.5") -> str:
    return "\n".join(PHASE.format(kind=k, duration=duration, noise=noise) for k in kinds)


BASE = phases("gains", "trajectory", "integration")
TABLES = {
    "plant": "mass = 0.0035\ndamping = 0.0\ncoulomb = 0.0\ndt_s = 0.001\n",
    "world": "motor_noise_std = 0.001\nposition_noise_std = 0.0003\nvelocity_noise_std = 0.0003\nseed = 0\nx0 = 0.0\nv0 = 0.0\n",
    "robot": "q_pos = 1.0\nq_vel = 0.0\nintegrate = true\ngain_window_s = 1.0\ntorque_limit = 1000.0\nseed = 1\n",
    "robot.sigma": "alpha = 1.0\nbeta = 2.0\nkappa = 0.0\n",
    "robot.stage1": "Q = [0.01, 0.01, 0.01, 0.01, 0.01, 0.01]\nR = [1e-7, 1e-7, 1e-7]\nP0 = [1e-4, 1e-4, 1e-4, 1.0, 1.0, 1.0]\ngains0 = [0.0, 0.0, 0.0]\n",
    "robot.stage2": "Q = [0.01, 0.01, 0.01, 0.01, 0.01, 0.01]\nR = [1e-7, 1e-7, 1e-7, 1e-7, 1e-7]\n",
    "robot.stage3": "Q = [0.01, 0.01]\nR_sensor = [1e-7, 1e-7]\nP0 = [0.01, 0.01]\n",
    "robot.stage3.channel": "gate = 4.0\nwindow_n0 = 80.0\nhold_max_s = 0.25\n",
    "partner": "gains = [0.0, 0.0, 2.0]\ntorque_limit = 1000.0\nestimates_robot = false\n",
    "rig": 'can = "udp:47100"\nnode_id = 1\nposition_unit = "deg"\ntorque_limit_nm = 3.0\nwatchdog_ms = 50\n'
    'feedback_timeout_ms = 20.0\nstop_time_limit_s = 0.2\nstop_time_constant_s = 0.004\n'
    'stop_torque_limit_nm = 3.0\nstop_rest_velocity_rad_s = 0.01\nvirtual_human = true\nlog = "out/rig_log.csv"\n'
    'stats = "out/rig_stats.json"\nring_capacity = 65536\n',
    "rig.realtime": "mlockall = true\n",
    "rig.range": "soft_min_deg = -40.0\nsoft_max_deg = 40.0\nhard_min_deg = -50.0\nhard_max_deg = 50.0\n",
}


def full(tables: dict[str, str] | None = None, head: str = BASE) -> str:
    t = dict(TABLES)
    t.update(tables or {})
    return head + "\n" + "\n".join(f"[{name}]\n{body}" for name, body in t.items() if body is not None)


def setting(table: str, key: str, value: str) -> str:
    """The base with `key = value` in `table` (replacing it, or added)."""
    lines = [ln for ln in TABLES[table].splitlines() if not ln.startswith(f"{key} =")]
    lines.append(f"{key} = {value}")
    return full({table: "\n".join(lines) + "\n"})


def edited(old: str, new: str) -> str:
    """The base phases with their first `old` replaced by `new`, every table present."""
    return full(head=BASE.replace(old, new, 1))


#: The first phase's robot target in BASE, which the shape cases replace.
SHAPE = '{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }'


def shape(new: str) -> str:
    """The base with the first phase's robot target shape `new`, every table present."""
    return edited(SHAPE, new)


CASES: dict[str, tuple[str, str]] = {}


def case(name: str, text: str, field: str, ext: str = "toml") -> None:
    assert name not in CASES, name
    CASES[f"{name}.{ext}"] = (text, field)


# --- valid files and edge values ---------------------------------------------
case("valid_full", full(), "valid")
case("valid_minimal", phases("gains"), "valid")
case("valid_defaults_only_tables", BASE + "\n[robot]\n[partner]\ngains = [0.0, 0.0, 1.0]\n[rig]\n", "valid")
case("valid_prior_gains", phases("trajectory") + "\n[robot]\nprior_partner_gains = [0.0, 0.0, 2.0]\n", "valid")
case("valid_lqr_partner", full({"partner": "q_pos = 20000.0\nq_vel = 2.0\n"}), "valid")
case("valid_full_cov", setting("robot.stage3", "Q", "[[0.01, 0.001], [0.001, 0.01]]"), "valid")
case("valid_watchdog_min", setting("rig", "watchdog_ms", "5"), "valid")
case("valid_watchdog_max", setting("rig", "watchdog_ms", "200"), "valid")
case("valid_stop_time_limit_zero", setting("rig", "stop_time_limit_s", "0.0"), "valid")
case("valid_stop_time_limit_max", setting("rig", "stop_time_limit_s", "2.0"), "valid")
case("valid_stop_time_constant_two_periods", setting("rig", "stop_time_constant_s", "0.002"), "valid")
case("valid_stop_torque_max", setting("rig", "stop_torque_limit_nm", "10.0"), "valid")
case("valid_velocity_margin_zero", setting("rig", "feedback_velocity_margin_rad_s", "0.0"), "valid")
case("valid_torque_max", setting("rig", "torque_limit_nm", "10.0"), "valid")
case("valid_ring_min", setting("rig", "ring_capacity", "1024"), "valid")
case("valid_feedback_velocity_max", setting("rig", "max_feedback_velocity_rad_s", "8.388607"), "valid")
case("valid_step_margin_zero", setting("rig", "feedback_step_margin_rad", "0.0"), "valid")
case("valid_missing_fraction_one", setting("rig", "max_missing_feedback_fraction", "1.0"), "valid")
case("valid_stale_ticks_min", setting("rig", "max_stale_feedback_ticks", "1"), "valid")
case("valid_estimator_errors_zero", setting("rig", "max_estimator_errors", "0"), "valid")
case("valid_socketcan", setting("rig", "can", '"socketcan:vcan0"'), "valid")
case("valid_udp_max_port", setting("rig", "can", '"udp:65535"'), "valid")
case("valid_dt_10ms", full({"plant": "dt_s = 0.01\n",
     "rig": "watchdog_ms = 200\nfeedback_timeout_ms = 100.0\nstop_time_constant_s = 0.02\n"}), "valid")
case("valid_fifo", setting("rig.realtime", "fifo_priority", "80"), "valid")
case("valid_spin", setting("rig.realtime", "spin_us", "100"), "valid")
case("valid_spin_below_half_period", setting("rig.realtime", "spin_us", "499"), "valid")
case("valid_spin_max_at_500_hz", full({"plant": "dt_s = 0.002\n", "rig.realtime": "spin_us = 900\n"}), "valid")
case("valid_node_15", setting("rig", "node_id", "15"), "valid")
case("valid_rad", setting("rig", "position_unit", '"rad"'), "valid")
case("valid_drive_hi5", setting("rig", "drive", '"hi5"'), "valid")
case("valid_drive_cia402", setting("rig", "drive", '"cia402"'), "valid")
case("valid_drive_cia402_node_15", full({"rig": 'drive = "cia402"\nnode_id = 15\n'}), "valid")
case("cia402_node_0", full({"rig": 'drive = "cia402"\nnode_id = 0\n'}), "rig.node_id")
case("valid_cia402_freshness_standard", full({"rig": 'drive = "cia402"\n', "rig.cia402": 'freshness = "standard"\n'}), "valid")
case("cia402_freshness_unknown", full({"rig": 'drive = "cia402"\n', "rig.cia402": 'freshness = "counter"\n'}), "rig.cia402.freshness")
case("valid_harmonics_defaults", BASE.replace(SHAPE,
     '{ kind = "harmonics", amplitude = 1e-4, omega_rad_s = 1.0 }', 1), "valid")
case("valid_sampled", BASE.replace(SHAPE,
     '{ kind = "sampled", samples = [0.0, 1.0, 0.5], dt_s = 0.5 }', 1), "valid")
case("valid_three_parts", BASE.replace(f'robot_target = [{SHAPE}]',
     'robot_target = [{ kind = "constant", value = 1.0 }, { kind = "square", amplitude = 1.0, period_s = 2.0 },'
     ' { kind = "chirp", amplitude = 2.0, f0_hz = 0.0, f1_hz = 2.0, duration_s = 2.0 }]', 1), "valid")
case("valid_four_phases", phases("gains", "trajectory", "integration", "integration"), "valid")
case("valid_json", json.dumps({"phases": [{"kind": "gains", "duration_s": 1.0,
     "robot_target": [{"kind": "square", "amplitude": 1.0, "period_s": 2.0}],
     "partner_target": [{"kind": "square", "amplitude": 1.0, "period_s": 2.0}]}]}), "valid", "json")

# --- syntax -------------------------------------------------------------------
case("syntax_unquoted_url", setting("rig", "can", "udp:47100"), "rig.can")
case("syntax_double_equals", full({"plant": "mass = = 0.0035\n"}), "plant.mass")
case("syntax_unclosed_table", full().replace("[plant]", "[plant"), "(file)")
case("syntax_duplicate_key", full({"plant": "mass = 1.0\nmass = 2.0\n"}), "plant.mass")
case("syntax_empty_file", "", "phases")
case("syntax_binary_garbage", "\x00\x01\x02 = ]]", "(file)")
case("syntax_json_trailing_comma", '{"phases": [],}', "(file)", "json")
case("syntax_json_not_object", "[1, 2, 3]", "(file)", "json")

# --- unknown and missing fields -----------------------------------------------
case("unknown_root", "foo = 1\n" + full(), "foo")
case("unknown_plant", setting("plant", "masss", "1.0"), "plant.masss")
case("unknown_robot", setting("robot", "qpos", "1.0"), "robot.qpos")
case("unknown_stage1", setting("robot.stage1", "q", "[1.0]"), "robot.stage1.q")
case("unknown_stage3", setting("robot.stage3", "R", "[1e-7, 1e-7]"), "robot.stage3.R")
case("unknown_rig", setting("rig", "watchdog", "50"), "rig.watchdog")
case("unknown_realtime", setting("rig.realtime", "priority", "50"), "rig.realtime.priority")
case("unknown_partner", setting("partner", "gain", "[0.0, 0.0, 2.0]"), "partner.gain")
case("unknown_world", setting("world", "sed", "1"), "world.sed")
case("unknown_phase_field", edited("target_noise_std = 0.5", "target_noise = 0.5"),
     "phases[0].target_noise")
case("unknown_shape_field", edited("period_s = 4.0 }", "period_s = 4.0, phase = 1.0 }"),
     "phases[0].robot_target[0].phase")
case("unknown_table", full({"robots": "q_pos = 1.0\n"}), "robots")
case("missing_phases", "\n".join(f"[{n}]\n{b}" for n, b in TABLES.items()), "phases")
case("missing_phase_kind", edited('kind = "gains"\n', ""), "phases[0].kind")
case("missing_phase_duration", edited("duration_s = 2.0\n", ""), "phases[0].duration_s")
case("missing_robot_target", edited(
    f'robot_target = [{SHAPE}]\n', ""), "phases[0].robot_target")
case("missing_shape_kind", edited('{ kind = "rounded_square", amplitude', "{ amplitude"),
     "phases[0].robot_target[0].kind")
case("missing_shape_period", edited(", period_s = 4.0 }", " }"),
     "phases[0].robot_target[0].period_s")
case("missing_partner_law", full({"partner": "torque_limit = 10.0\n"}), "partner")

# --- wrong types -------------------------------------------------------------
for table, key, value, name in [
    ("rig", "can", "5", "can_int"),
    ("rig", "can", "[1]", "can_list"),
    ("rig", "node_id", '"1"', "node_string"),
    ("rig", "node_id", "1.5", "node_float"),
    ("rig", "watchdog_ms", "50.0", "watchdog_float"),
    ("rig", "virtual_human", '"yes"', "virtual_human_string"),
    ("rig", "position_unit", '"degree"', "position_unit_bad"),
    ("rig", "position_unit", "1", "position_unit_int"),
    ("rig", "drive", '"canopen"', "drive_bad"),
    ("rig", "drive", '"CiA402"', "drive_uppercase"),
    ("rig", "drive", "402", "drive_int"),
    ("rig", "log", "3", "log_int"),
    ("rig", "ring_capacity", "1e12", "ring_float"),
    ("rig.realtime", "mlockall", "1", "mlockall_int"),
    ("rig.realtime", "cpu", '"0"', "cpu_string"),
    ("rig.realtime", "spin_us", "100.0", "spin_float"),
    ("plant", "mass", '"heavy"', "mass_string"),
    ("plant", "dt_s", "true", "dt_bool"),
    ("world", "seed", "-3", "seed_negative"),
    ("world", "seed", "1.5", "seed_float"),
    ("robot", "integrate", '"true"', "integrate_string"),
    ("robot", "seed", '"1"', "robot_seed_string"),
    ("robot.stage1", "Q", "0.01", "stage1_Q_scalar"),
    ("robot.stage1", "R", '["a", "b", "c"]', "stage1_R_strings"),
    ("robot.stage1", "gains0", "[0.0, 0.0]", "gains0_short"),
    ("robot.stage2", "R", "[[1e-7, 0.0], 1e-7, 1e-7, 1e-7, 1e-7]", "stage2_R_mixed"),
    ("robot.stage3", "P0", "{ a = 1 }", "stage3_P0_table"),
    ("partner", "gains", "[0.0, 1.0]", "partner_gains_short"),
    ("partner", "gains", "[0.0, 1.0, 2.0, 3.0]", "partner_gains_long"),
    ("partner", "gains", '"0, 0, 2"', "partner_gains_string"),
    ("partner", "estimates_robot", "0", "estimates_robot_int"),
    ("robot.sigma", "alpha", '"1"', "alpha_string"),
]:
    case(f"type_{name}", setting(table, key, value), f"{table}.{key}")
case("type_plant_not_table", "plant = 5\n" + BASE, "plant")
case("type_phases_table", "[phases]\nkind = \"gains\"\n", "phases")
case("type_phase_kind_int", edited('kind = "gains"', "kind = 3"), "phases[0].kind")
case("type_target_not_list", edited(
    f'robot_target = [{SHAPE}]',
    'robot_target = "square"'), "phases[0].robot_target")
case("type_shape_string", shape('"rounded_square"'), "phases[0].robot_target[0]")
case("type_shape_amplitude_string", edited("amplitude = 8.0", 'amplitude = "8"'),
     "phases[0].robot_target[0].amplitude")
case("type_shape_kind_int", edited('kind = "rounded_square"', "kind = 2"),
     "phases[0].robot_target[0].kind")
case("type_shape_unknown_kind", edited('kind = "rounded_square"', 'kind = "triangle"'),
     "phases[0].robot_target[0].kind")
case("type_harmonics_float", shape('{ kind = "harmonics", amplitude = 1.0, omega_rad_s = 1.0, harmonics = 2.5 }'),
     "phases[0].robot_target[0].harmonics")
case("type_phase_kind_unknown", edited('kind = "trajectory"', 'kind = "trajectry"'), "phases[1].kind")
case("type_json_string_number", json.dumps({"phases": [{"kind": "gains", "duration_s": "1",
     "robot_target": [{"kind": "square", "amplitude": 1.0, "period_s": 2.0}],
     "partner_target": [{"kind": "square", "amplitude": 1.0, "period_s": 2.0}]}]}), "phases[0].duration_s", "json")
case("type_json_null", json.dumps({"phases": [{"kind": "gains", "duration_s": 1.0,
     "robot_target": [{"kind": "square", "amplitude": None, "period_s": 2.0}],
     "partner_target": [{"kind": "square", "amplitude": 1.0, "period_s": 2.0}]}]}),
     "phases[0].robot_target[0].amplitude", "json")

# --- out of range and non-finite ---------------------------------------------
for table, key, value, name in [
    ("rig", "torque_limit_nm", "0.0", "torque_zero"),
    ("rig", "torque_limit_nm", "-3.0", "torque_negative"),
    ("rig", "torque_limit_nm", "50.0", "torque_huge"),
    ("rig", "torque_limit_nm", "nan", "torque_nan"),
    ("rig", "torque_limit_nm", "inf", "torque_inf"),
    ("rig", "watchdog_ms", "0", "watchdog_zero"),
    ("rig", "watchdog_ms", "65535", "watchdog_65535"),
    ("rig", "watchdog_ms", "201", "watchdog_201"),
    ("rig", "watchdog_ms", "4", "watchdog_4"),
    ("rig", "feedback_timeout_ms", "1e300", "feedback_timeout_1e300"),
    ("rig", "feedback_timeout_ms", "0.0", "feedback_timeout_zero"),
    ("rig", "feedback_timeout_ms", "nan", "feedback_timeout_nan"),
    ("rig", "stop_time_limit_s", "1e300", "stop_time_limit_1e300"),
    ("rig", "stop_time_limit_s", "-0.1", "stop_time_limit_negative"),
    ("rig", "stop_time_limit_s", "inf", "stop_time_limit_inf"),
    ("rig", "stop_time_constant_s", "0.0", "stop_time_constant_zero"),
    ("rig", "stop_time_constant_s", "nan", "stop_time_constant_nan"),
    ("rig", "stop_torque_limit_nm", "0.0", "stop_torque_zero"),
    ("rig", "stop_torque_limit_nm", "50.0", "stop_torque_huge"),
    ("rig", "stop_rest_velocity_rad_s", "0.0", "stop_rest_velocity_zero"),
    ("rig", "stop_rest_velocity_rad_s", "-0.01", "stop_rest_velocity_negative"),
    ("rig", "feedback_velocity_margin_rad_s", "-0.1", "velocity_margin_negative"),
    ("rig", "feedback_velocity_margin_rad_s", "inf", "velocity_margin_inf"),
    ("rig", "ring_capacity", "1000000000000", "ring_1e12"),
    ("rig", "ring_capacity", "1023", "ring_small"),
    ("rig", "node_id", "16", "node_16"),
    ("rig", "max_feedback_velocity_rad_s", "0.0", "feedback_velocity_zero"),
    ("rig", "max_feedback_velocity_rad_s", "8.4", "feedback_velocity_past_field"),
    ("rig", "max_feedback_velocity_rad_s", "nan", "feedback_velocity_nan"),
    ("rig", "feedback_step_margin_rad", "-0.01", "step_margin_negative"),
    ("rig", "feedback_step_margin_rad", "1e300", "step_margin_1e300"),
    ("rig", "max_missing_feedback_fraction", "1.5", "missing_fraction_over_one"),
    ("rig", "max_missing_feedback_fraction", "inf", "missing_fraction_inf"),
    ("rig", "max_stale_feedback_ticks", "0", "stale_ticks_zero"),
    ("rig", "max_stale_feedback_ticks", "100001", "stale_ticks_huge"),
    ("rig", "max_estimator_errors", "-1", "estimator_errors_negative"),
    ("rig", "max_estimator_errors", "1000001", "estimator_errors_huge"),
    ("rig", "node_id", "-1", "node_negative"),
    ("rig.realtime", "fifo_priority", "0", "fifo_zero"),
    ("rig.realtime", "fifo_priority", "100", "fifo_100"),
    ("rig.realtime", "spin_us", "-1", "spin_negative"),
    ("rig.realtime", "spin_us", "901", "spin_901"),
    ("plant", "dt_s", "0.0", "dt_zero"),
    ("plant", "dt_s", "1.0", "dt_one_second"),
    ("plant", "dt_s", "1e-6", "dt_tiny"),
    ("plant", "mass", "-1.0", "mass_negative"),
    ("plant", "mass", "0.0", "mass_zero"),
    ("plant", "mass", "nan", "mass_nan"),
    ("plant", "damping", "-0.1", "damping_negative"),
    ("world", "motor_noise_std", "-1.0", "motor_noise_negative"),
    ("world", "position_noise_std", "inf", "position_noise_inf"),
    ("world", "x0", "nan", "x0_nan"),
    ("robot", "q_pos", "0.0", "q_pos_zero"),
    ("robot", "q_vel", "-1.0", "q_vel_negative"),
    ("robot", "gain_window_s", "0.0", "gain_window_zero"),
    ("robot", "torque_limit", "inf", "robot_torque_inf"),
    ("robot", "torque_limit", "-1.0", "robot_torque_negative"),
    ("robot", "prior_partner_gains", "[0.0, nan, 2.0]", "prior_nan"),
    ("robot.sigma", "alpha", "0.0", "alpha_zero"),
    ("robot.sigma", "alpha", "2.0", "alpha_two"),
    ("robot.sigma", "kappa", "-10.0", "kappa_very_negative"),
    ("robot.sigma", "beta", "nan", "beta_nan"),
    ("robot.stage1", "Q", "[0.01, 0.01, 0.01, 0.01, 0.01]", "Q_five"),
    ("robot.stage1", "R", "[1e-7, -1e-7, 1e-7]", "R_negative"),
    ("robot.stage1", "R", "[1e-7, nan, 1e-7]", "R_nan"),
    ("robot.stage1", "P0", "[1e-4, 1e-4, 1e-4, 1.0, 1.0, 1e9]", "P0_huge"),
    ("robot.stage1", "gains0", "[0.0, inf, 0.0]", "gains0_inf"),
    ("robot.stage2", "P0", "[[1.0, 2.0], [0.0, 1.0]]", "stage2_P0_2x2"),
    ("robot.stage3", "Q", "[[0.01, 0.02], [0.0, 0.01]]", "stage3_Q_asymmetric"),
    ("robot.stage3", "Q", "[[0.01, 0.02], [0.02, 0.01]]", "stage3_Q_indefinite"),
    ("robot.stage3", "R_sensor", "[0.0, 1e-7]", "stage3_R_singular"),
    ("robot.stage3.channel", "gate", "0.0", "channel_gate_zero"),
    ("robot.stage3.channel", "hold_max_s", "-1.0", "channel_hold_negative"),
    ("partner", "torque_limit", "0.0", "partner_torque_zero"),
    ("partner", "gains", "[0.0, 0.0, inf]", "partner_gain_inf"),
    ("partner", "gains", "[0.0, 0.0, 1e9]", "partner_gain_huge"),
]:
    case(f"range_{name}", setting(table, key, value), f"{table}.{key}")
case("range_timeout_below_period", full({"plant": "dt_s = 0.01\n", "rig": "watchdog_ms = 200\nfeedback_timeout_ms = 5.0\n"}),
     "rig.feedback_timeout_ms")
case("range_watchdog_below_two_periods", full({"plant": "dt_s = 0.01\n", "rig": "watchdog_ms = 15\nfeedback_timeout_ms = 50.0\n"}),
     "rig.watchdog_ms")
# Within the schema's bounds but shorter than two loop periods (the brake would oscillate).
case("range_stop_time_constant_one_period", setting("rig", "stop_time_constant_s", "0.001"),
     "rig.stop_time_constant_s")
case("range_stop_time_constant_at_10ms", full({"plant": "dt_s = 0.01\n",
     "rig": "watchdog_ms = 200\nfeedback_timeout_ms = 100.0\n"}), "rig.stop_time_constant_s")
# Within the schema's 0..900 us but not below half the 1 ms period (500 us).
case("range_spin_half_period", setting("rig.realtime", "spin_us", "500"), "rig.realtime.spin_us")
case("range_spin_over_half_period", setting("rig.realtime", "spin_us", "600"), "rig.realtime.spin_us")
case("range_spin_901_at_500_hz", full({"plant": "dt_s = 0.002\n", "rig.realtime": "spin_us = 901\n"}),
     "rig.realtime.spin_us")
case("range_phase_duration_zero", edited("duration_s = 2.0", "duration_s = 0.0"), "phases[0].duration_s")
case("range_phase_duration_subtick", edited("duration_s = 2.0", "duration_s = 0.0001"),
     "phases[0].duration_s")
case("range_phase_duration_day", edited("duration_s = 2.0", "duration_s = 86400.0"), "phases[0].duration_s")
case("range_phase_duration_nan", edited("duration_s = 2.0", "duration_s = nan"), "phases[0].duration_s")
case("range_target_noise_negative", edited("target_noise_std = 0.5", "target_noise_std = -1.0"),
     "phases[0].target_noise_std")
case("range_amplitude_inf", edited("amplitude = 8.0", "amplitude = inf"),
     "phases[0].robot_target[0].amplitude")
case("range_period_negative", edited("period_s = 4.0", "period_s = -4.0"),
     "phases[0].robot_target[0].period_s")
case("range_chirp_negative_f0", shape('{ kind = "chirp", amplitude = 2.0, f0_hz = -1.0, f1_hz = 2.0, duration_s = 2.0 }'),
     "phases[0].robot_target[0].f0_hz")
case("range_harmonics_zero", shape('{ kind = "harmonics", amplitude = 1.0, omega_rad_s = 1.0, harmonics = 0 }'),
     "phases[0].robot_target[0].harmonics")
case("range_sampled_empty", shape('{ kind = "sampled", samples = [], dt_s = 0.1 }'), "phases[0].robot_target[0].samples")
case("range_sampled_nan", shape('{ kind = "sampled", samples = [0.0, nan], dt_s = 0.1 }'), "phases[0].robot_target[0].samples[1]")
case("range_four_shapes", edited(
    f'robot_target = [{SHAPE}]',
    "robot_target = [" + ", ".join(['{ kind = "constant", value = 1.0 }'] * 4) + "]"), "phases[0].robot_target")
case("range_no_shapes", edited(
    f'partner_target = [{SHAPE}]', "partner_target = []"),
     "phases[0].partner_target")

# --- rig.friction (the compensation sensaug calibrate writes) ----------------------
case("valid_rig_friction", full({"rig.friction": "coulomb_nm = 0.02\nviscous_nm_s_per_rad = 0.01\n"}), "valid")
case("rig_friction_coulomb_above_torque_limit", full({"rig.friction": "coulomb_nm = 5.0\n"}), "rig.friction.coulomb_nm")
case("rig_friction_viscous_negative", full({"rig.friction": "viscous_nm_s_per_rad = -0.01\n"}),
     "rig.friction.viscous_nm_s_per_rad")
case("rig_friction_viscous_overcompensating", full({"rig.friction": "viscous_nm_s_per_rad = 2.0\n"}),
     "rig.friction.viscous_nm_s_per_rad")
case("rig_friction_band_nan", full({"rig.friction": "coulomb_band_rad_s = nan\n"}), "rig.friction.coulomb_band_rad_s")

# --- bad URLs ------------------------------------------------------------------
for value, name in [
    ('"tcp:1"', "tcp"), ('"udp:0"', "udp_zero"), ('"udp:70000"', "udp_70000"), ('"udp:abc"', "udp_abc"),
    ('""', "empty"), ('"udp:"', "udp_empty"), ('"socketcan:"', "socketcan_empty"),
    ('"socketcan:averyveryverylongname"', "socketcan_long"), ('"socketcan:can 0"', "socketcan_space"),
    ('"udp:-1"', "udp_negative"), ('"UDP:47100"', "udp_upper"), ('"udp:47100 "', "udp_trailing_space"),
]:
    case(f"url_{name}", setting("rig", "can", value), "rig.can")
case("url_log_empty", setting("rig", "log", '""'), "rig.log")

# --- output paths (checked against the file system: docs/safety.md, "Output paths";
# tests/test_config_corpus.py adds FIFOs and links made at test time) ---------------
case("out_log_dev_full", setting("rig", "log", '"/dev/full"'), "rig.log")
case("out_log_dev_null", setting("rig", "log", '"/dev/null"'), "rig.log")
case("out_stats_dev_full", setting("rig", "stats", '"/dev/full"'), "rig.stats")
case("out_log_directory", setting("rig", "log", '"/tmp"'), "rig.log")
case("out_log_trailing_slash", setting("rig", "log", '"out/rig_log/"'), "rig.log")
case("out_log_in_a_device", setting("rig", "log", '"/dev/null/rig_log.csv"'), "rig.log")
case("out_same_path", full({"rig": 'log = "out/same.csv"\nstats = "out/same.csv"\n'}), "rig.stats")
case("out_same_path_spelled_twice", full({"rig": 'log = "out/x.csv"\nstats = "out/./sub/../x.csv"\n'}), "rig.stats")
case("out_stats_is_the_logs_partial", full({"rig": 'log = "out/x.csv"\nstats = "out/x.csv.partial"\n'}), "rig.stats")

# --- phase orders and counts ---------------------------------------------------
case("order_trajectory_first", phases("trajectory", "gains"), "phases[0].kind")
case("order_integration_only", phases("integration"), "phases[0].kind")
case("order_gains_after_integration", phases("integration", "gains"), "phases[0].kind")
case("order_five_phases", phases("gains", "gains", "trajectory", "integration", "integration"), "phases")
case("order_zero_phases", "phases = []\n", "phases")
case("lqr_partner_and_gains", full({"partner": "gains = [0.0, 0.0, 2.0]\nq_pos = 1.0\n"}), "partner")
case("lqr_q_vel_alone", full({"partner": "q_vel = 1.0\n"}), "partner.q_vel")
case("lqr_partner_nan", full({"partner": "q_pos = nan\n"}), "partner.q_pos")

# --- the partner's goal integration and state source (simulation section) ----------
INTEGRATING = "q_pos = 20000.0\nq_vel = 2.0\nestimates_robot = true\n"
case("valid_partner_integration", full({"partner": INTEGRATING, "partner.integration": "target_noise_std = 0.03\n"}), "valid")
case("valid_partner_acts_on_true", setting("partner", "acts_on", '"true"'), "valid")
case("partner_acts_on_unknown", setting("partner", "acts_on", '"estimated"'), "partner.acts_on")
case("partner_integration_no_estimates", full({"partner.integration": "integrate = true\n"}), "partner.integration")
case("partner_integration_acts_on_true",
     full({"partner": INTEGRATING + 'acts_on = "true"\n', "partner.integration": "seed = 3\n"}), "partner.acts_on")
case("partner_integration_noise_negative",
     full({"partner": INTEGRATING, "partner.integration": "target_noise_std = -0.1\n"}), "partner.integration.target_noise_std")
case("partner_integration_unknown_field",
     full({"partner": INTEGRATING, "partner.integration": "noise = 0.1\n"}), "partner.integration.noise")
case("partner_integration_trajectory_first",
     full({"partner": INTEGRATING, "partner.integration": "seed = 3\n",
           "robot": TABLES["robot"] + "prior_partner_gains = [0.0, 2.0, 141.4]\n"},
          head=phases("trajectory", "integration")),
     "partner.integration")

# --- the range of motion (rig.range, docs/safety.md) ------------------------------
case("valid_range_stated_wall", full({"rig.range": "wall_stiffness_nm_per_deg = 1.0\n"
     "wall_damping_nm_s_per_deg = 0.015\nspeed_damping_nm_s_per_deg = 0.0\n"}), "valid")
case("valid_range_asymmetric", full({"rig.range": "soft_min_deg = -60.0\nsoft_max_deg = 30.0\n"
     "hard_min_deg = -70.0\nhard_max_deg = 35.0\n"}), "valid")
case("range_soft_window_empty", setting("rig.range", "soft_min_deg", "40.0"), "rig.range.soft_max_deg")
case("range_hard_max_inside_window", setting("rig.range", "hard_max_deg", "35.0"), "rig.range.hard_max_deg")
case("range_hard_min_inside_window", setting("rig.range", "hard_min_deg", "-40.0"), "rig.range.hard_min_deg")
case("range_beyond_half_turn", setting("rig.range", "hard_max_deg", "181.0"), "rig.range.hard_max_deg")
case("range_ramp_zero", setting("rig.range", "ramp_width_deg", "0.0"), "rig.range.ramp_width_deg")
case("range_ramp_negative", setting("rig.range", "ramp_width_deg", "-1.0"), "rig.range.ramp_width_deg")
case("range_ramps_overlap", setting("rig.range", "ramp_width_deg", "41.0"), "rig.range.ramp_width_deg")
case("range_hard_speed_below_soft", setting("rig.range", "hard_speed_deg_s", "150.0"), "rig.range.hard_speed_deg_s")
case("range_hard_speed_over_feedback_bound", setting("rig.range", "hard_speed_deg_s", "500.0"),
     "rig.range.hard_speed_deg_s")
case("range_wall_too_stiff", setting("rig.range", "wall_stiffness_nm_per_deg", "20.0"),
     "rig.range.wall_stiffness_nm_per_deg")
case("range_wall_damping_over_half_per_tick", setting("rig.range", "wall_damping_nm_s_per_deg", "0.05"),
     "rig.range.wall_damping_nm_s_per_deg")
case("range_speed_damping_nan", setting("rig.range", "speed_damping_nm_s_per_deg", "nan"),
     "rig.range.speed_damping_nm_s_per_deg")
case("range_wall_stiffness_inf", setting("rig.range", "wall_stiffness_nm_per_deg", "inf"),
     "rig.range.wall_stiffness_nm_per_deg")
case("range_unknown_field", setting("rig.range", "soft_max", "30.0"), "rig.range.soft_max")
case("range_wall_at_10_ms", full({"plant": "dt_s = 0.01\n",
     "rig": "watchdog_ms = 200\nfeedback_timeout_ms = 100.0\nstop_time_constant_s = 0.02\n",
     "rig.range": "wall_stiffness_nm_per_deg = 1.0\n"}), "rig.range.wall_stiffness_nm_per_deg")

# --- sizes ------------------------------------------------------------------------
big = ", ".join(["0.0"] * 250_000)
case("size_over_1mib", BASE.replace(SHAPE,
     f'{{ kind = "sampled", samples = [{big}], dt_s = 0.001 }}', 1), "(file)")

case("size_many_samples", BASE.replace(SHAPE,
     "{ kind = \"sampled\", samples = [" + ", ".join(["1.0"] * 100_001) + "], dt_s = 0.001 }", 1),
     "phases[0].robot_target[0].samples")


def main() -> None:
    for old in HERE.glob("*.toml"):
        old.unlink()
    for old in HERE.glob("*.json"):
        if old.name != "EXPECTED.json":
            old.unlink()
    expected = {}
    for name, (text, field) in sorted(CASES.items()):
        (HERE / name).write_text(text)
        expected[name] = field
    (HERE / "EXPECTED.json").write_text(json.dumps(expected, indent=1, sort_keys=True) + "\n")
    print(f"{len(CASES)} files")


if __name__ == "__main__":
    main()
