#!/usr/bin/env python3
"""Independent numba peer of axisbench's one-axis servo + plant model (presets/default.ron).

What it is
    A re-implementation, written from the project's src/{servo,plant,machine}.rs, of the T3 loop of
    one axis of `presets/default.ron`:
      servo : position P loop (kp) on the compensated command, velocity feed-forward (vff) from
              the raw interpolated command, velocity PI loop (kv, ki, conditional integration),
              acceleration feed-forward (aff * M, one acceleration per T2 segment of the raw
              command, as the amplifier computes it), torque limit, current loop as a
              first-order lag;
      plant : rigid drive with lost motion (two bodies inside the 8 um gap, inelastic impact at
              the flank), Coulomb + viscous friction with exact stick, motor-encoder quantization
              (semi-closed loop), screw thermal growth (temperature from friction power + motion
              heat; it moves the table, not the feedback).
    Off in default.ron and therefore not implemented: Stribeck, stroke friction, gravity, lead
    error, scale quantization / scale feedback, two-mass coupling, servo compensations.
    The NC (interpolation, acc/dec) and the backlash position compensation are NOT re-run: the
    peer is driven by the trace's own command columns, one row per T3: x.cmd (raw, drives the
    feed-forwards) and x.cmd_comp (raw + backlash correction, drives the position loop).

What it measures
    check : x.pos, x.torque (and motor_pos, torque_cmd, friction, screw temperature) against an
            axisbench reference trace (trace_every must be 1, the default). With --exact the
            inputs are the bit-exact f64 commands dumped by dump_inputs.rs instead of the CSV's
            mm values (which round-trip to m with a 1-ulp error on ~2 % of rows).
    speed : throughput of the numba kernel alone (recording off, after JIT warm-up, best of
            --reps, the command tiled to --steps T3 steps), alternated --rounds times with
            `axisbench bench` (its first line, axes=1 recording=off) and, if the harness binary
            exists, with axisbench's own Machine on default.ron and (with --exact) axisbench's
            own Servo::step + AxisPlant::step alone on the same input (ab_default_bench.rs);
            then the same kernel source as plain Python (NUMBA_DISABLE_JIT=1, Python lists).

Usage
    All commands from the project's root, with PEER = the folder of this file.
    ./target/release/axisbench simulate --preset presets/default.ron --out /tmp/peer_ref.csv
    # optional, for --exact and the harness figures: two tiny Rust programs linked against the
    # project's prebuilt rlib (nothing in the project is written)
    D=target/release/deps; R=$(ls $D/libaxisbench-*.rlib); mkdir -p /tmp/peer_dump
    for s in dump_inputs ab_default_bench; do rustc --edition 2024 -C opt-level=3 \\
        -C target-cpu=x86-64-v2 -o /tmp/peer_dump/$s $PEER/$s.rs \\
        --extern axisbench=$R -L dependency=$D; done
    /tmp/peer_dump/dump_inputs presets/default.ron /tmp/peer_dump/default.bin
    PY=python3 (with numpy and numba)
    $PY $PEER/axis_peer.py check /tmp/peer_ref.csv [--exact /tmp/peer_dump/default.bin]
    $PY $PEER/axis_peer.py speed /tmp/peer_ref.csv [--exact /tmp/peer_dump/default.bin] [--steps 6000000]
        [--reps 5] [--rounds 3] [--py-steps 300000] [--no-bench] [--harness BIN]
"""

import argparse
import math
import os
import statistics
import subprocess
import sys
import time

import numpy as np
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


def constants(t3):
    """Derived step constants, as Servo::new / AxisPlant::retune compute them."""
    p = P
    lead_m = p["lead_mm"] * 1e-3
    fpt = 2.0 * math.pi / lead_m                      # force_per_torque
    m_m = p["motor_inertia_kgm2"] * fpt * fpt          # reflected motor inertia
    m_t = p["table_mass_kg"]
    h = t3                                             # rigid: one plant sub-step per T3
    visc = p["viscous_n_s_per_m"]
    q = lead_m / float(p["motor_counts_per_rev"])
    r = p["t2_s"] / t3
    n23 = int(round(r))
    assert abs(r - n23) <= 1e-9 * n23
    c = np.array([
        t3, 1.0 / t3, t3 * n23,                                      # 0 t3, 1 inv_t3, 2 t2
        p["kp_per_s"], p["kv_n_s_per_m"], p["ki_per_s"], p["vff"],   # 3..6
        p["aff"] * (m_m + m_t),                                      # 7 aff_mass
        1.0 - math.exp(-t3 / p["current_lag_s"]),                    # 8 cur_alpha
        p["torque_limit_nm"] * fpt,                                  # 9 force limit
        m_m, m_t, 0.5 * p["width_um"] * 1e-6,                        # 10 m_m, 11 m_t, 12 b/2
        h / (m_m + m_t), (m_m + m_t) / h, 1.0 / (1.0 + h * visc / (m_m + m_t)),  # 13-15 all
        h / m_t, m_t / h, 1.0 / (1.0 + h * visc / m_t),              # 16-18 table body
        h / m_m,                                                     # 19 motor h/m
        p["coulomb_n"], visc,                                        # 20, 21
        q, 1.0 / q,                                                  # 22, 23 encoder quantum
        p["friction_heat_share"], p["motion_heat_w_s_per_m"],        # 24, 25
        1.0 / p["heat_capacity_j_per_k"], p["loss_w_per_k"],         # 26, 27
        p["ambient_c"], p["alpha_per_k"], p["reference_c"],          # 28, 29, 30
        p["fixed_end_mm"] * 1e-3, p["initial_c"],                    # 31, 32
        p["initial_pos_mm"] * 1e-3, fpt, h,                          # 33 x0, 34 fpt, 35 h
    ])
    return c, n23


@njit(cache=True)
def friction_step(h_over_m, m_over_h, visc_inv, coulomb, visc, v, f_other):
    """FrictionModel::step without Stribeck/stroke (scale = 1): (new velocity, friction)."""
    v_free = v + h_over_m * f_other
    f_stop = -m_over_h * v_free
    if abs(f_stop) <= coulomb:
        return 0.0, f_stop
    d = 1.0 if v_free > 0.0 else -1.0
    v_new = (v_free - d * h_over_m * coulomb) * visc_inv
    if v_new * d <= 0.0:
        return 0.0, f_stop
    return v_new, -d * coulomb - visc * v_new


@njit(cache=True)
def kernel(raw, cmd, n23, c, record, out):
    """Runs len(cmd) T3 steps of one axis. raw/cmd in m. If record, out[:, k] gets the trace
    row of step k (state at the start of the step, torque applied during it), in trace units:
    pos mm, torque N*m, motor_pos mm, torque_cmd N*m, friction N, screw temp degC (after the
    step). Returns a checksum of the final state."""
    n = len(cmd)
    t3 = c[0]; inv_t3 = c[1]; t2 = c[2]
    kp = c[3]; kv = c[4]; ki = c[5]; vff = c[6]; aff_m = c[7]; alpha = c[8]; lim = c[9]
    m_m = c[10]; m_t = c[11]; b2 = c[12]
    a_hm = c[13]; a_mh = c[14]; a_vi = c[15]
    t_hm = c[16]; t_mh = c[17]; t_vi = c[18]; mot_hm = c[19]
    coul = c[20]; visc = c[21]; q = c[22]; qinv = c[23]
    share = c[24]; motion = c[25]; inv_cap = c[26]; loss = c[27]; amb = c[28]
    alpha_t = c[29]; ref_c = c[30]; fixed = c[31]; temp = c[32]; x0 = c[33]; fpt = c[34]
    h = c[35]
    # plant: rest on the + flank (no gravity), motor at x0
    contact = 1
    x_m = x0; v_m = 0.0; v_t = 0.0
    x_t = x_m - contact * b2
    enc = math.floor(x_m * qinv + 0.5) * q
    pos = x_t + alpha_t * (temp - ref_c) * (x_t - fixed)
    # servo
    integ = 0.0; force = 0.0; prev_cmd = x0; hist = x0
    # amplifier's T2 bookkeeping for the acceleration feed-forward
    prev_raw = x0; seg_vel = 0.0; acc = 0.0
    for k in range(n):
        if k % n23 == 0:
            e = k + n23 - 1
            if e >= n:
                e = n - 1
            v_seg = (raw[e] - prev_raw) / t2
            acc = (v_seg - seg_vel) / t2
            seg_vel = v_seg
            prev_raw = raw[e]
        # ---- servo (Servo::step), feedback = motor encoder
        vel_fb = (enc - hist) * inv_t3
        hist = enc
        ff = raw[k]
        vel_ff = vff * (ff - prev_cmd) * inv_t3
        prev_cmd = ff
        ferr = cmd[k] - enc
        ev = kp * ferr + vel_ff - vel_fb
        integ_new = integ + kv * ki * ev * t3
        f_raw = kv * ev + integ_new + aff_m * acc
        f_cmd = min(max(f_raw, -lim), lim)
        if (f_cmd == f_raw or (f_raw > lim and integ_new < integ)
                or (f_raw < -lim and integ_new > integ)):
            integ = integ_new
        force += alpha * (f_cmd - force)
        if record:
            out[0, k] = pos * 1e3
            out[1, k] = force / fpt
            out[2, k] = x_m * 1e3
            out[3, k] = f_cmd / fpt
        # ---- plant (AxisPlant::step_play, one sub-step)
        done = False
        if contact != 0:
            v, fr = friction_step(a_hm, a_mh, a_vi, coul, visc, v_t, force)
            f_contact = m_t * (v - v_t) / h - fr
            if f_contact * contact >= 0.0:
                v_t = v; v_m = v
                x_m += h * v
                x_t = x_m - contact * b2
                done = True
            else:
                contact = 0
        if not done:
            v_m += mot_hm * force
            x_m += h * v_m
            v, fr = friction_step(t_hm, t_mh, t_vi, coul, visc, v_t, 0.0)
            v_t = v
            x_t += h * v
            gap = x_m - x_t
            side = 1 if gap >= b2 else (-1 if gap <= -b2 else 0)
            if side != 0:
                v = (m_m * v_m + m_t * v_t) / (m_m + m_t)
                v_m = v; v_t = v
                contact = side
                x_t = x_m - side * b2
        # ---- screw thermal, outputs (refresh_out)
        temp += t3 * inv_cap * (share * abs(fr * v_t) + motion * abs(v_t) - loss * (temp - amb))
        enc = math.floor(x_m * qinv + 0.5) * q
        pos = x_t + alpha_t * (temp - ref_c) * (x_t - fixed)
        if record:
            out[4, k] = fr
            out[5, k] = temp
    return pos + force + temp + integ


# ----------------------------------------------------------------------------------------------
def read_trace(path):
    meta, header_line = {}, 0
    with open(path) as f:
        for i, line in enumerate(f):
            if line.startswith("#"):
                k, _, v = line[1:].partition(":")
                meta[k.strip()] = v.strip()
            else:
                header = line.strip().split(",")
                header_line = i
                break
    data = np.loadtxt(path, delimiter=",", skiprows=header_line + 1)
    return meta, {h: data[:, j] for j, h in enumerate(header)}


def load_inputs(path):
    meta, cols = read_trace(path)
    t3 = float(meta["t3_s"])
    t = cols["t[s]"]
    steps = np.round(np.diff(t) / t3)
    if not np.all(steps == 1):
        sys.exit(f"{path}: trace is decimated (rows {set(steps.tolist())} T3 apart); "
                 "rerun simulate with --set scenario.trace_every=1")
    raw = cols["x.cmd[mm]"] / 1e3
    cmd = cols["x.cmd_comp[mm]"] / 1e3
    return t3, raw, cmd, cols


def check(path, exact=None):
    t3, raw, cmd, cols = load_inputs(path)
    if exact:
        # Bit-exact f64 servo inputs dumped by dump_inputs.rs (cmd_raw_m, cmd_m, force_n per T3):
        # the CSV's mm values round-trip to m with a 1-ulp error on ~2 % of rows.
        d = np.fromfile(exact).reshape(-1, 3)
        assert len(d) == len(cmd) and np.all(d[:, 1] * 1e3 == cols["x.cmd_comp[mm]"])
        raw, cmd = np.ascontiguousarray(d[:, 0]), np.ascontiguousarray(d[:, 1])
    c, n23 = constants(t3)
    out = np.zeros((6, len(cmd)))
    kernel(raw, cmd, n23, c, True, out)
    src = f"exact f64 inputs from {exact}" if exact else "inputs x.cmd, x.cmd_comp from the CSV"
    print(f"{path}: {len(cmd)} T3 steps, t3 = {t3} s, n23 = {n23}; {src}")
    rows = [("x.pos[mm]", 0, 1e3, "um"), ("x.torque[N*m]", 1, 1.0, "N*m"),
            ("x.motor_pos[mm]", 2, 1e3, "um"), ("x.torque_cmd[N*m]", 3, 1.0, "N*m"),
            ("x.friction[N]", 4, 1.0, "N"), ("temp.x_screw[degC]", 5, 1.0, "K")]
    for name, i, scale, unit in rows:
        d = (out[i] - cols[name]) * scale
        print(f"  {name:20s} max |diff| {np.max(np.abs(d)):.3e} {unit:4s} "
              f"rms {np.sqrt(np.mean(d * d)):.3e} {unit:4s} "
              f"(signal range {np.ptp(cols[name] * scale):.4g} {unit}); "
              f"bit-identical rows {np.mean(out[i] == cols[name]) * 100:.2f} %")


def time_kernel(raw, cmd, n23, c, reps):
    out = np.zeros((6, 1))
    best = []
    for _ in range(reps):
        t0 = time.perf_counter()
        kernel(raw, cmd, n23, c, False, out)
        best.append(time.perf_counter() - t0)
    return len(cmd) / min(best)


def axisbench_bench(steps):
    """One `axisbench bench` run: its step-alone, recording-off and recording-on figures."""
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
    return out


def harness_bench(harness, steps, *mode):
    """axisbench's own code via ab_default_bench.rs: the Machine on presets/default.ron as
    shipped (NC + comps + servo + plant), or with mode = ("kernel", BIN) its Servo::step +
    AxisPlant::step alone on the same inputs as the peer."""
    args = [harness, *mode[:1], "presets/default.ron", *mode[1:], str(steps)]
    r = subprocess.run(args, cwd=MAIN, capture_output=True, text=True, check=True)
    return float(r.stdout.split("axis_steps_per_s=")[1])


def tiled_inputs(path, exact, steps):
    """Servo inputs (raw, cmd in m) of the trace, or the exact dump, tiled to `steps` T3."""
    t3, raw0, cmd0, _ = load_inputs(path)
    if exact:
        d = np.fromfile(exact).reshape(-1, 3)
        raw0, cmd0 = d[:, 0], d[:, 1]
    tiles = -(-steps // len(cmd0))
    return (t3, np.ascontiguousarray(np.tile(raw0, tiles)[:steps]),
            np.ascontiguousarray(np.tile(cmd0, tiles)[:steps]))


def speed(path, exact, steps, reps, rounds, py_steps, bench, harness):
    """Alternates the numba kernel with one `axisbench bench` per round, so both see the same
    machine load; prints min/median/max of each figure and the ratios to the peer."""
    t3, raw, cmd = tiled_inputs(path, exact, steps)
    c, n23 = constants(t3)
    kernel(raw[:1000], cmd[:1000], n23, c, False, np.zeros((6, 1)))  # JIT warm-up
    res = {}
    names = {"step": "axisbench AxisLoop::step alone (default.ron x, same input)",
             "off": "axisbench bench axes=1 recording=off (full model + NC)",
             "on": "axisbench bench axes=1 recording=on"}
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
        if exact:
            cmdline += ["--exact", exact]
        r = subprocess.run(cmdline, env=env, capture_output=True, text=True, check=True)
        print(r.stdout.rstrip())


def pyspeed(path, exact, py_steps):
    t3, raw, cmd = tiled_inputs(path, exact, py_steps)
    c, n23 = constants(t3)
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
    a.add_argument("--exact", metavar="BIN", help="f64 inputs dumped by dump_inputs.rs")
    b = sub.add_parser("speed", help="throughput, alternated with `axisbench bench`")
    b.add_argument("trace")
    b.add_argument("--exact", metavar="BIN", help="f64 inputs dumped by dump_inputs.rs "
                   "(also enables the Servo+Plant-only axisbench figure)")
    b.add_argument("--steps", type=int, default=6_000_000)
    b.add_argument("--reps", type=int, default=5)
    b.add_argument("--rounds", type=int, default=3)
    b.add_argument("--py-steps", type=int, default=300_000)
    b.add_argument("--no-bench", action="store_true")
    b.add_argument("--harness", default="/tmp/peer_dump/ab_default_bench",
                   help="ab_default_bench.rs binary (skipped if missing)")
    c = sub.add_parser("pyspeed", help="plain-Python throughput (run with NUMBA_DISABLE_JIT=1)")
    c.add_argument("trace")
    c.add_argument("--py-steps", type=int, default=300_000)
    c.add_argument("--exact", metavar="BIN")
    args = ap.parse_args()
    if args.cmd == "check":
        check(args.trace, args.exact)
    elif args.cmd == "pyspeed":
        pyspeed(args.trace, args.exact, args.py_steps)
    else:
        speed(args.trace, args.exact, args.steps, args.reps, args.rounds, args.py_steps,
              not args.no_bench, args.harness)


if __name__ == "__main__":
    main()
