#!/usr/bin/env python3
"""Independent numba peer of axisbench's one-axis servo + plant model (presets/default.ron).

What it is
    A re-implementation, written from the project's src/{drive,servo,plant,machine}.rs, of the
    T3 loop of one axis of `presets/default.ron` (AxisLoop::step of a plain axis):
      servo : position P loop (kp) on the compensated command, velocity feed-forward (vff) from
              the raw interpolated command, velocity PI loop (kv, ki, conditional integration),
              acceleration feed-forward (aff * M, one acceleration per T2 segment of the raw
              command: SegmentAcc), torque limit, current loop as a first-order lag;
      plant : rigid drive with lost motion (two bodies inside the 8 um gap, tested at
              mid-sub-step; inelastic impact at the flank), Coulomb + viscous friction with exact stick, motor-encoder quantization
              (round half to even; semi-closed loop), screw thermal growth (temperature from
              friction power + motion heat; it moves the table, not the feedback).
    Off in default.ron and therefore not implemented: Stribeck, stroke friction, gravity, lead
    error, scale quantization / scale feedback, two-mass coupling, servo compensations.
    The NC (interpolation, acc/dec) and the backlash position compensation are NOT re-run: the
    peer is driven by the trace's own command columns, one row per T3: x.cmd (raw, drives the
    feed-forwards and the per-T2 acceleration) and x.cmd_comp (raw + backlash correction,
    drives the position loop).
    Every constant and every step expression is written with the operations, and the order
    of the operations, of the Rust (Servo::step sums what is known a period ahead first and
    the encoder reading last; FrictionModel::step uses the per-body constants of
    FrictionModel::body), so that the peer and the model agree bit for bit.

What it measures
    check : x.pos, x.torque (and motor_pos, torque_cmd, friction, screw temperature) against an
            axisbench reference trace (trace_every must be 1, the default). The CSV's mm
            columns are read by shifting the decimal point of each cell (the way axisbench
            wrote them from its SI f64), which gives the model's f64 in m exactly; dividing the
            parsed mm value by 1e3 is off by an ulp on ~17 % of the command rows.
    speed : throughput of the numba kernel alone (recording off, after JIT warm-up, best of
            --reps, the command tiled to --steps T3 steps), alternated --rounds times with
            `axisbench bench` (its lines "step alone", "axes=1 recording=off",
            "axes=1 recording=on" and "machine on default.ron ... recording=off"); then the
            same kernel source as plain Python (NUMBA_DISABLE_JIT=1, Python lists).

Usage
    All commands from the project's root, with PEER = the folder of this file and PY = a
    python3 with numpy and numba. AXISBENCH (default target/release/axisbench) names the
    binary `speed` runs.
    ./target/release/axisbench simulate --preset presets/default.ron --out /tmp/peer_ref.csv
    $PY $PEER/axis_peer.py check /tmp/peer_ref.csv
    $PY $PEER/axis_peer.py speed /tmp/peer_ref.csv [--steps 6000000] [--reps 5] [--rounds 3]
        [--py-steps 300000] [--no-bench]
"""

import argparse
import math
import os
import statistics
import subprocess
import sys
import time

import numpy as np
import numba
from numba import njit

AXISBENCH = os.environ.get("AXISBENCH", "target/release/axisbench")
MAIN = os.environ.get("AXISBENCH_ROOT", ".")

# --- presets/default.ron, axis x (values copied; derived constants below use the same
# --- expressions, in the same order, as the Rust code so that the numbers agree bit for bit).
P = dict(
    t2_s=0.001,
    motor_inertia_kgm2=0.0015, lead_mm=10.0, table_mass_kg=300.0,
    kp_per_s=50.0, kv_n_s_per_m=560000.0, ki_per_s=125.0, vff=1.0, aff=1.0,
    current_lag_s=0.0003, torque_limit_nm=20.0,
    motor_counts_per_rev=1048576,                        # quantize_motor: true, feedback: motor
    coulomb_n=250.0, viscous_n_s_per_m=800.0,            # friction enabled, stribeck/stroke off
    width_um=8.0,                                        # lost_motion enabled
    alpha_per_k=1.15e-05, heat_capacity_j_per_k=5400.0, loss_w_per_k=3.0,
    friction_heat_share=0.5, motion_heat_w_s_per_m=60.0, ambient_c=20.0, initial_c=20.0,
    reference_c=20.0, fixed_end_mm=0.0,                  # screw_thermal enabled
    initial_pos_mm=0.0,
)


def constants(t3, t2):
    """Derived step constants, with the expressions (and their order) of Gains::new,
    AxisPlant::retune, FrictionModel::body, ScrewThermal::from_params and SegmentAcc::new."""
    p = P
    lead_m = p["lead_mm"] / 1000.0                     # units::mm_to_m
    fpt = math.tau / lead_m                            # force_per_torque
    m_m = p["motor_inertia_kgm2"] * fpt * fpt          # reflected motor inertia
    m_t = p["table_mass_kg"]
    m_all = m_m + m_t                                  # total_mass_kg
    h = t3 / 1.0                                       # rigid: one plant sub-step per T3
    visc = p["viscous_n_s_per_m"]
    q = lead_m / float(p["motor_counts_per_rev"])
    r = t2 / t3
    n23 = int(round(r))
    assert abs(r - n23) <= 1e-9 * n23
    kv, ki, kp = p["kv_n_s_per_m"], p["ki_per_s"], p["kp_per_s"]
    integ = kv * ki * t3                               # integ_gain_n_per_mps
    kv_total = kv + integ
    k_enc = kp + 1.0 / t3                              # vel_filter_avg2: false
    cur_alpha = 1.0 - math.exp(-t3 / p["current_lag_s"])

    def body(m):                                       # FrictionModel::body
        visc_inv = 1.0 / (1.0 + h * visc / m)
        return [h / m, m / h, visc_inv, h / m * visc_inv]

    c = np.array([
        t3, 1.0 / t3, 1.0 / t2,                                      # 0 t3, 1 vel scale, 2 1/t2
        kp, kv_total, integ, p["vff"] / t3,                          # 3..6
        p["aff"] * m_all,                                            # 7 aff_mass
        cur_alpha, 1.0 - cur_alpha,                                  # 8 cur_alpha, 9 cur_keep
        p["torque_limit_nm"] * fpt,                                  # 10 force limit
        k_enc, kv_total * k_enc,                                     # 11 k_enc, 12 kv_k_enc
        m_m, m_t, 0.5 * (p["width_um"] / 1e6),                       # 13 m_m, 14 m_t, 15 b/2
        *body(m_all),                                                # 16-19 body_all
        *body(m_t),                                                  # 20-23 body_table
        h / m_m,                                                     # 24 motor h/m
        p["coulomb_n"], visc,                                        # 25, 26
        q, 1.0 / q,                                                  # 27, 28 encoder quantum
        p["friction_heat_share"], p["motion_heat_w_s_per_m"],        # 29, 30
        1.0 / p["heat_capacity_j_per_k"], p["loss_w_per_k"],         # 31, 32
        p["ambient_c"], p["alpha_per_k"], p["reference_c"],          # 33, 34, 35
        p["fixed_end_mm"] / 1000.0, p["initial_c"],                  # 36, 37
        p["initial_pos_mm"] / 1000.0, fpt, h,                        # 38 x0, 39 fpt, 40 h
    ])
    return c, n23


@njit(cache=True)
def friction_step(h_over_m, m_over_h, visc_inv, kin_per_n, coulomb, visc, v, f_drive):
    """FrictionModel::step for a plain axis (no Stribeck, no stroke friction, no load force):
    (new velocity, friction). Same operations in the same order as the Rust."""
    v_ahead = v + h_over_m * 0.0                  # f_known_n = gravity + ext = 0
    v_free = v_ahead + h_over_m * f_drive
    kin = kin_per_n * coulomb
    f_stop = -m_over_h * v_free
    if abs(f_stop) <= coulomb:
        return 0.0, f_stop
    v_new = v_free * visc_inv - math.copysign(kin, v_free)
    if v_new * v_free <= 0.0:
        return 0.0, f_stop
    return v_new, -math.copysign(coulomb, v_free) - visc * v_new


if numba.config.DISABLE_JIT:
    def round_even(x):
        """f64::round_ties_even (Python's round() rounds ties to even; np.rint on a Python
        float would make the plain-Python timing mostly numpy scalar overhead)."""
        return float(round(x))
else:
    @njit(cache=True)
    def round_even(x):
        """f64::round_ties_even."""
        return np.rint(x)


@njit(cache=True)
def kernel(raw, cmd, n23, c, record, out):
    """Runs len(cmd) T3 steps of one axis. raw/cmd in m. If record, out[:, k] gets the trace
    row of step k (state at the start of the step, torque applied during it), SI: pos m,
    torque N*m, motor_pos m, torque_cmd N*m, friction N, screw temp degC (after the step).
    Returns a checksum of the final state."""
    n = len(cmd)
    t3 = c[0]; vs = c[1]; inv_t2 = c[2]
    kp = c[3]; kv_tot = c[4]; ig = c[5]; vff = c[6]; aff_m = c[7]
    alpha = c[8]; keep = c[9]; lim = c[10]; k_enc = c[11]; kvk_enc = c[12]
    m_m = c[13]; m_t = c[14]; b2 = c[15]
    a_hm = c[16]; a_mh = c[17]; a_vi = c[18]; a_kin = c[19]
    t_hm = c[20]; t_mh = c[21]; t_vi = c[22]; t_kin = c[23]; mot_hm = c[24]
    coul = c[25]; visc = c[26]; q = c[27]; qinv = c[28]
    share = c[29]; motion = c[30]; inv_cap = c[31]; loss = c[32]; amb = c[33]
    alpha_t = c[34]; ref_c = c[35]; fixed = c[36]; temp = c[37]; x0 = c[38]; fpt = c[39]
    h = c[40]
    hh = 0.5 * h                                   # plant::trapezoid
    # plant (AxisPlant::new/place): at rest on the + flank (no gravity), encoder reading x0
    contact = 1
    x_t = x0 - contact * b2
    x_m = x_t + contact * b2
    v_m = 0.0; v_t = 0.0
    enc = round_even(x_m * qinv) * q
    # PosMap: pos = gain * x_t + offset, the screw growth taken from the temperature one
    # period before the period it is used in (AxisPlant::pos_map; no lead error here)
    g = alpha_t * (temp - ref_c)
    gain = 1.0 + g + 0.0; offset = (0.0 - 0.0 * x_t) - g * fixed
    pos = gain * x_t + offset
    next_gain = gain; next_offset = offset
    # servo (Servo::new)
    integ = 0.0; force = 0.0; prev_ff = x0; hist = enc
    # SegmentAcc: one acceleration per T2 segment of the raw command
    prev_end = x0; seg_vel = 0.0; acc = 0.0
    for k in range(n):
        if k % n23 == 0:
            e = k + n23 - 1
            if e >= n:
                e = n - 1
            end = raw[e]
            v_seg = (end - prev_end) * inv_t2
            acc = (v_seg - seg_vel) * inv_t2
            seg_vel = v_seg
            prev_end = end
        # ---- servo (Servo::step), feedback = motor encoder, vel_filter_avg2 off
        older = hist
        hist = enc
        vel_ff = vff * (raw[k] - prev_ff)
        prev_ff = raw[k]
        ahead = kp * cmd[k] + (vs * older + (vel_ff + 0.0))
        base = aff_m * acc + (integ + 0.0)
        early = kv_tot * ahead + base
        ev = ahead - k_enc * enc
        f_raw = early - kvk_enc * enc
        integ_new = integ + ig * ev
        f_cmd = min(max(f_raw, -lim), lim)
        if (f_cmd == f_raw or (f_raw > lim and integ_new < integ)
                or (f_raw < -lim and integ_new > integ)):
            integ = integ_new
        force = keep * force + alpha * f_cmd
        if record:
            out[0, k] = pos
            out[1, k] = force / fpt
            out[2, k] = x_m
            out[3, k] = f_cmd / fpt
        # ---- plant (AxisPlant::step_play, one sub-step, f_load = 0)
        gain = next_gain; offset = next_offset
        g = alpha_t * (temp - ref_c)
        next_gain = 1.0 + g + 0.0
        next_offset = (0.0 - 0.0 * (x_t + 2.0 * t3 * v_t)) - g * fixed
        done = False
        if contact != 0:
            v, fr = friction_step(a_hm, a_mh, a_vi, a_kin, coul, visc, v_t, force)
            f_contact = t_mh * (v - v_t) - 0.0 - fr
            if f_contact * contact >= 0.0:
                x_m = (x_m + hh * v_m) + hh * v
                v_t = v; v_m = v
                x_t = x_m - contact * b2
                done = True
            else:
                contact = 0
        if not done:
            v_m0 = v_m
            v_m += mot_hm * force
            x_m = (x_m + hh * v_m0) + hh * v_m
            v, fr = friction_step(t_hm, t_mh, t_vi, t_kin, coul, visc, v_t, 0.0)
            x_t = (x_t + hh * v_t) + hh * v
            v_t = v
            gap = x_m - x_t + 0.5 * h * (v_m - v_t)       # the gap at mid-sub-step
            side = 1 if gap >= b2 else (-1 if gap <= -b2 else 0)
            if side != 0:
                v = (m_m * v_m + m_t * v_t) / (m_m + m_t)
                v_m = v; v_t = v
                contact = side
                x_t = x_m - side * b2
        # ---- screw thermal (ScrewThermal::step), outputs (refresh_out)
        q_w = share * abs(fr * v_t) + motion * abs(v_t)
        temp += t3 * inv_cap * (q_w - loss * (temp - amb))
        enc = round_even(x_m * qinv) * q
        pos = gain * x_t + offset
        if record:
            out[4, k] = fr
            out[5, k] = temp
    return pos + force + temp + integ


# ----------------------------------------------------------------------------------------------
# Display units of the CSV and the decimal shift that turns them into the model's SI. The
# trace writes each SI f64 by shifting the decimal point of its shortest round-trip text, so
# shifting it back (cell's exponent − 3, then float()) gives the model's f64 exactly; cell / 1e3 does not
# always (1-ulp differences on ~2 % of rows).
SHIFT = {"mm": -3, "mm/s": -3}


def shifted(cell, shift):
    """The f64 nearest to the decimal `cell` times 10**shift (Python's float() of a decimal
    text is correctly rounded)."""
    if not cell:
        return math.nan
    if not shift:
        return float(cell)
    mant, _, exp = cell.lower().partition("e")
    return float(f"{mant}e{int(exp or 0) + shift}")


def read_trace(path):
    """(metadata, {column name: SI values}); a column in mm is parsed as cell + 'e-3'."""
    meta, header = {}, None
    with open(path) as f:
        for line in f:
            if line.startswith("#"):
                k, _, v = line[1:].partition(":")
                meta[k.strip()] = v.strip()
            elif header is None:
                header = line.strip().split(",")
                rows = [[] for _ in header]
            else:
                for col, cell in zip(rows, line.rstrip("\n").split(",")):
                    col.append(cell)
    cols = {}
    for name, cells in zip(header, rows):
        unit = name[name.index("[") + 1:-1] if name.endswith("]") else ""
        sh = SHIFT.get(unit, 0)
        cols[name] = np.array([shifted(x, sh) for x in cells])
    return meta, cols


def load_inputs(path):
    """T3, T2 and the servo inputs of a trace (m): x.cmd (raw, drives the feed-forwards and
    the per-T2 acceleration) and x.cmd_comp (the position loop's command)."""
    meta, cols = read_trace(path)
    t3, t2 = float(meta["t3_s"]), float(meta.get("t2_s", P["t2_s"]))
    t = cols["t[s]"]
    steps = np.round(np.diff(t) / t3)
    if not np.all(steps == 1):
        sys.exit(f"{path}: trace is decimated (rows {set(steps.tolist())} T3 apart); "
                 "rerun simulate with --set scenario.trace_every=1")
    raw = np.ascontiguousarray(cols["x.cmd[mm]"])
    cmd = np.ascontiguousarray(cols["x.cmd_comp[mm]"])
    return t3, t2, raw, cmd, cols


def check(path):
    t3, t2, raw, cmd, cols = load_inputs(path)
    c, n23 = constants(t3, t2)
    out = np.zeros((6, len(cmd)))
    kernel(raw, cmd, n23, c, True, out)
    print(f"{path}: {len(cmd)} T3 steps, t3 = {t3} s, n23 = {n23}; "
          "inputs x.cmd, x.cmd_comp from the CSV (decimal-shifted to m, exact)")
    rows = [("x.pos[mm]", 0, 1e6, "um"), ("x.torque[N*m]", 1, 1.0, "N*m"),
            ("x.motor_pos[mm]", 2, 1e6, "um"), ("x.torque_cmd[N*m]", 3, 1.0, "N*m"),
            ("x.friction[N]", 4, 1.0, "N"), ("temp.x_screw[degC]", 5, 1.0, "K")]
    first = len(cmd)
    for name, i, scale, unit in rows:
        d = (out[i] - cols[name]) * scale
        same = out[i] == cols[name]
        if not same.all():
            first = min(first, int(np.argmin(same)))
        print(f"  {name:20s} max |diff| {np.max(np.abs(d)):.3e} {unit:4s} "
              f"rms {np.sqrt(np.mean(d * d)):.3e} {unit:4s} "
              f"(signal range {np.ptp(cols[name] * scale):.4g} {unit}); "
              f"bit-identical rows {np.mean(same) * 100:.2f} %")
    if first < len(cmd):
        print(f"  first row that differs: {first} (t = {cols['t[s]'][first]} s)")
    else:
        print("  every row of every compared column is bit-identical")


def time_kernel(raw, cmd, n23, c, reps):
    out = np.zeros((6, 1))
    best = []
    for _ in range(reps):
        t0 = time.perf_counter()
        kernel(raw, cmd, n23, c, False, out)
        best.append(time.perf_counter() - t0)
    return len(cmd) / min(best)


def axisbench_bench(steps):
    """One `axisbench bench` run: its step-alone, recording-off, recording-on and
    machine-on-default.ron (recording off) figures."""
    r = subprocess.run([AXISBENCH, "bench", "--steps", str(steps)], cwd=MAIN,
                       capture_output=True, text=True, check=True)
    out = {}
    for l in r.stdout.splitlines():
        v = float(l.split("axis_steps_per_s=")[1]) if "axis_steps_per_s=" in l else None
        if l.startswith("step alone"):
            out["step"] = v
        elif l.startswith("axes=1 recording=off"):
            out["off"] = v
        elif l.startswith("axes=1 recording=on"):
            out["on"] = v
        elif l.startswith("machine on default.ron") and "recording=off" in l:
            out["default"] = v
    return out


def tiled_inputs(path, steps):
    """Servo inputs (raw, cmd in m) of the trace, tiled to `steps` T3."""
    t3, t2, raw0, cmd0, _ = load_inputs(path)
    tiles = -(-steps // len(cmd0))
    return (t3, t2, np.ascontiguousarray(np.tile(raw0, tiles)[:steps]),
            np.ascontiguousarray(np.tile(cmd0, tiles)[:steps]))


def speed(path, steps, reps, rounds, py_steps, bench):
    """Alternates the numba kernel with one `axisbench bench` per round, so both see the same
    machine load; prints min/median/max of each figure and the ratios to the peer."""
    t3, t2, raw, cmd = tiled_inputs(path, steps)
    c, n23 = constants(t3, t2)
    kernel(raw[:1000], cmd[:1000], n23, c, False, np.zeros((6, 1)))  # JIT warm-up
    res = {}
    names = {"step": "axisbench AxisLoop::step alone (default.ron x, same input)",
             "off": "axisbench bench axes=1 recording=off (full model + NC)",
             "on": "axisbench bench axes=1 recording=on",
             "default": "axisbench Machine on default.ron (recording off)"}
    for r in range(rounds):
        if bench:
            for k, v in axisbench_bench(steps).items():
                res.setdefault(names[k], []).append(v)
        res.setdefault(f"numba peer kernel (best of {reps})", []).append(
            time_kernel(raw, cmd, n23, c, reps))
        print(f"round {r + 1}: " + ", ".join(f"{v[-1] / 1e6:.2f}" for v in res.values())
              + " M axis-steps/s", flush=True)
    print(f"{steps} T3 steps per run; M axis-steps/s over {rounds} alternated rounds:")
    peer = statistics.median(res[f"numba peer kernel (best of {reps})"])
    for name, x in res.items():
        print(f"  {name:58s} min {min(x) / 1e6:6.2f}  median {statistics.median(x) / 1e6:6.2f}"
              f"  max {max(x) / 1e6:6.2f}  = {statistics.median(x) / peer:4.2f}x peer")
    if py_steps:
        env = dict(os.environ, NUMBA_DISABLE_JIT="1")
        cmdline = [sys.executable, __file__, "pyspeed", path, "--py-steps", str(py_steps)]
        r = subprocess.run(cmdline, env=env, capture_output=True, text=True, check=True)
        print(r.stdout.rstrip())


def pyspeed(path, py_steps):
    t3, t2, raw, cmd = tiled_inputs(path, py_steps)
    c, n23 = constants(t3, t2)
    rl, cl, cc = raw.tolist(), cmd.tolist(), c.tolist()
    t0 = time.perf_counter()
    kernel(rl, cl, n23, cc, False, None)
    dt = time.perf_counter() - t0
    print(f"  pure-Python peer (same source, NUMBA_DISABLE_JIT=1, lists, {py_steps} steps): "
          f"{py_steps / dt / 1e6:.3f} M axis-steps/s")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("check", help="agreement with an axisbench reference trace")
    a.add_argument("trace")
    b = sub.add_parser("speed", help="throughput, alternated with `axisbench bench`")
    b.add_argument("trace")
    b.add_argument("--steps", type=int, default=6_000_000)
    b.add_argument("--reps", type=int, default=5)
    b.add_argument("--rounds", type=int, default=3)
    b.add_argument("--py-steps", type=int, default=300_000)
    b.add_argument("--no-bench", action="store_true")
    c = sub.add_parser("pyspeed", help="plain-Python throughput (run with NUMBA_DISABLE_JIT=1)")
    c.add_argument("trace")
    c.add_argument("--py-steps", type=int, default=300_000)
    args = ap.parse_args()
    if args.cmd == "check":
        check(args.trace)
    elif args.cmd == "pyspeed":
        pyspeed(args.trace, args.py_steps)
    else:
        speed(args.trace, args.steps, args.reps, args.rounds, args.py_steps, not args.no_bench)


if __name__ == "__main__":
    main()
