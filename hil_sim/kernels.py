"""Numba step kernel of the simulated GMA: one function advances every physical state by dt.

The batch runner (`run_kernel`) calls the very same `step_kernel` once per sample, so a batch run
and a real-time stepping run agree sample for sample. All state lives in three preallocated
arrays (float state, float parameters, uint64 RNG state) plus a ring buffer for the transport
delay; nothing allocates inside a step.

Physics (see docs/hil_sim.md): amplifier current loop (first order) -> coil field H = n*I ->
eddy-current lag of the field inside the rod (first order) -> Jiles-Atherton magnetisation with
the Sablik-Jiles magnetoelastic field (stress enters the effective field, and optionally the
pinning) -> quadratic magnetostriction + creep + thermal expansion = free stroke -> rod stiffness
and load mass (second order) -> transport delay -> sensors (noise, quantisation).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

MU0 = 4.0e-7 * math.pi
G = 9.80665

# ---- parameter vector layout (float64) --------------------------------------------------------
P_ON_EDDY = 0
P_ON_DYN = 1
P_ON_THERMAL = 2
P_ON_CREEP = 3
P_ON_DELAY = 4
P_ON_AMP = 5
P_ON_NOISE = 6
P_ON_WIDTH = 7          # stress-dependent pinning (loop width follows stress)
P_TURNS_PER_M = 8       # coil field per ampere, A/m per A
P_MS = 9                # saturation magnetisation, A/m
P_A = 10                # anhysteretic shape, A/m
P_K = 11                # pinning, A/m (loop half-width in field)
P_C = 12                # reversibility 0..1
P_ALPHA = 13            # interdomain coupling
P_LAMBDA_SAT = 14       # saturation magnetostriction (3/2 lambda_s), 1
P_STRESS_COUPLING = 15  # multiplier on the Sablik-Jiles magnetoelastic field
P_K_STRESS = 16         # relative pinning change per MPa of extra compression (option)
P_SIGMA_REF = 17        # reference stress for the pinning law, MPa
P_ROD_LEN_UM = 18       # rod length in um
P_ROD_AREA = 19         # rod cross-section, m^2
P_PRELOAD_N = 20
P_SPRING_N_PER_UM = 21  # preload spring stiffness
P_STIFF_N_PER_UM = 22   # rod + spring stiffness for the dynamics
P_MOVING_MASS = 23      # effective moving mass without load, kg
P_ZETA = 24             # damping ratio (taken as independent of the load)
P_TAU_EDDY = 25
P_TAU_AMP = 26
P_I_MIN = 27
P_I_MAX = 28
P_R_COIL = 29
P_R_TH = 30             # K/W
P_TAU_TH = 31           # s
P_T_AMB = 32
P_DRIFT_UM_PER_K = 33
P_CREEP_TAU0 = 34       # three creep time constants
P_CREEP_TAU1 = 35
P_CREEP_TAU2 = 36
P_CREEP_G0 = 37         # and their gains (fraction of the magnetostrictive stroke)
P_CREEP_G1 = 38
P_CREEP_G2 = 39
P_DELAY_S = 40
P_NOISE_X = 41          # std, um
P_QUANT_X = 42          # um per count
P_NOISE_I = 43
P_QUANT_I = 44
P_NOISE_F = 45
P_QUANT_F = 46
P_NOISE_T = 47
P_QUANT_T = 48
P_DT_SUB = 49           # largest internal sub-step, s
P_DH_MAX = 50           # largest field increment per Jiles-Atherton integration step, A/m
P_STRESS_SAT = 51       # MPa scale at which the magnetoelastic field saturates (0: linear in stress)
N_PARAMS = 52

# ---- state vector layout (float64) ------------------------------------------------------------
S_T = 0          # plant time, s
S_I = 1          # amplifier output current, A
S_H = 2          # field inside the rod, A/m
S_M = 3          # magnetisation, A/m
S_DIR = 4        # last field direction (+1 / -1)
S_XMS = 5        # magnetostrictive stroke (no creep, no thermal), um
S_XFREE = 6      # free stroke: magnetostriction + creep + thermal, um
S_X = 7          # load position, um
S_V = 8          # load velocity, um/s
S_ACC = 9        # load acceleration, um/s^2
S_TEMP = 10      # coil/rod temperature, C
S_C0 = 11        # creep states, um
S_C1 = 12
S_C2 = 13
S_MASS = 14      # load mass, kg
S_FORCE = 15     # true rod force (compressive, positive), N
S_SIGMA = 16     # true stress, MPa (compression negative)
S_XOUT = 17      # true displacement at the sensor after the delay, um
S_MEAS_X = 18    # measured values
S_MEAS_I = 19
S_MEAS_F = 20
S_MEAS_SIGMA = 21
S_MEAS_T = 22
S_CMD = 23       # last command, A
S_HEAD = 24      # ring-buffer head index
S_COUNT = 25     # ring-buffer fill
N_STATE = 26

DELAY_BUFFER = 32768  # sub-steps of history kept for the transport delay (0.8 s at 25 us)


@njit(cache=True)
def _uniform(rng: np.ndarray) -> float:
    """splitmix64: tiny, seedable, and private to this plant (numba's global RNG is shared)."""
    rng[0] += np.uint64(0x9E3779B97F4A7C15)
    z = rng[0]
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return (float(z >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)


@njit(cache=True)
def _normal(rng: np.ndarray) -> float:
    u1 = _uniform(rng)
    u2 = _uniform(rng)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True)
def _measure(value: float, std: float, quantum: float, rng: np.ndarray, noisy: bool) -> float:
    if not noisy:
        return value
    v = value + std * _normal(rng)
    if quantum > 0.0:
        v = quantum * math.floor(v / quantum + 0.5)
    return v


@njit(cache=True)
def _langevin(x: float) -> tuple:
    """Langevin function and its derivative, series near zero to avoid cancellation."""
    if abs(x) < 1e-3:
        return x / 3.0 - x * x * x / 45.0, 1.0 / 3.0 - x * x / 15.0
    cth = 1.0 / math.tanh(x)
    return cth - 1.0 / x, 1.0 / (x * x) - (cth * cth - 1.0)


@njit(cache=True)
def _dm_dh(h: float, m: float, delta: float, alpha_tot: float, k: float, p: np.ndarray) -> float:
    """Jiles-Atherton differential susceptibility dM/dH with the magnetoelastic coupling."""
    ms = p[P_MS]
    a = p[P_A]
    c = p[P_C]
    he = h + alpha_tot * m
    lan, dlan = _langevin(he / a)
    man = ms * lan
    dman = ms / a * dlan
    mirr = (m - c * man) / (1.0 - c)
    diff = man - mirr
    chi_irr = diff / (delta * k)
    if chi_irr < 0.0:       # no negative irreversible susceptibility (Deane/Jiles correction)
        chi_irr = 0.0
    num = (1.0 - c) * chi_irr + c * dman
    return num / (1.0 - alpha_tot * num)


@njit(cache=True)
def _alpha_total(p: np.ndarray, sigma_mpa: float) -> float:
    """alpha + Sablik-Jiles magnetoelastic term 9*lambda_s*sigma/(2*mu0*Ms^2), lambda_s=2/3 lambda_sat.

    With a saturation scale S > 0 the stress enters as S*tanh(sigma/S): once compression has
    turned the domains perpendicular to the rod, more compression changes the loop less (the
    stroke-vs-prestress curves of Terfenol-D flatten at high prestress).
    """
    lam_s = p[P_LAMBDA_SAT] * (2.0 / 3.0)
    ms = p[P_MS]
    s_sat = p[P_STRESS_SAT]
    sig = s_sat * math.tanh(sigma_mpa / s_sat) if s_sat > 0.0 else sigma_mpa
    return p[P_ALPHA] + p[P_STRESS_COUPLING] * 9.0 * lam_s * sig * 1e6 / (2.0 * MU0 * ms * ms)


@njit(cache=True)
def _pinning(p: np.ndarray, sigma_mpa: float) -> float:
    k = p[P_K]
    if p[P_ON_WIDTH] > 0.5:
        extra = (-sigma_mpa) - (-p[P_SIGMA_REF])
        k = k * (1.0 + p[P_K_STRESS] * extra)
        if k < 0.05 * p[P_K]:
            k = 0.05 * p[P_K]
    return k


@njit(cache=True)
def _advance_magnetics(state: np.ndarray, p: np.ndarray, h_new: float) -> None:
    """Integrate M along the field path from state[S_H] to h_new (midpoint rule, capped dH)."""
    h = state[S_H]
    dh_total = h_new - h
    if dh_total == 0.0:
        return
    delta = 1.0 if dh_total > 0.0 else -1.0
    state[S_DIR] = delta
    sigma = state[S_SIGMA]
    alpha_tot = _alpha_total(p, sigma)
    k = _pinning(p, sigma)
    n = int(math.ceil(abs(dh_total) / p[P_DH_MAX]))
    if n < 1:             # a subnormal increment divided by the cap underflows to zero
        n = 1
    dh = dh_total / n
    m = state[S_M]
    for _ in range(n):
        k1 = _dm_dh(h, m, delta, alpha_tot, k, p)
        k2 = _dm_dh(h + 0.5 * dh, m + 0.5 * dh * k1, delta, alpha_tot, k, p)
        m += dh * k2
        h += dh
    state[S_M] = m
    state[S_H] = h_new


@njit(cache=True)
def _substep(state: np.ndarray, p: np.ndarray, cmd: float, dt: float) -> None:
    """Advance every physical state by one internal sub-step dt."""
    # amplifier current loop
    if p[P_ON_AMP] > 0.5:
        state[S_I] += (cmd - state[S_I]) * (1.0 - math.exp(-dt / p[P_TAU_AMP]))
        if abs(cmd - state[S_I]) < 1e-12:      # settled: stop the decay before subnormal floats
            state[S_I] = cmd
    else:
        state[S_I] = cmd
    h_coil = p[P_TURNS_PER_M] * state[S_I]
    # eddy currents: the field inside the rod lags the coil field
    if p[P_ON_EDDY] > 0.5:
        h_rod = state[S_H] + (h_coil - state[S_H]) * (1.0 - math.exp(-dt / p[P_TAU_EDDY]))
        if abs(h_coil - h_rod) < 1e-9:
            h_rod = h_coil
    else:
        h_rod = h_coil
    _advance_magnetics(state, p, h_rod)
    mr = state[S_M] / p[P_MS]
    x_ms = p[P_ROD_LEN_UM] * p[P_LAMBDA_SAT] * mr * mr
    state[S_XMS] = x_ms
    x_free = x_ms
    # creep: three first-order relaxations towards a fraction of the magnetostrictive stroke
    if p[P_ON_CREEP] > 0.5:
        state[S_C0] += (p[P_CREEP_G0] * x_ms - state[S_C0]) * (1.0 - math.exp(-dt / p[P_CREEP_TAU0]))
        state[S_C1] += (p[P_CREEP_G1] * x_ms - state[S_C1]) * (1.0 - math.exp(-dt / p[P_CREEP_TAU1]))
        state[S_C2] += (p[P_CREEP_G2] * x_ms - state[S_C2]) * (1.0 - math.exp(-dt / p[P_CREEP_TAU2]))
        x_free += state[S_C0] + state[S_C1] + state[S_C2]
    # Joule heating with one thermal time constant; differential expansion shifts the stroke
    if p[P_ON_THERMAL] > 0.5:
        i = state[S_I]
        t_ss = p[P_T_AMB] + i * i * p[P_R_COIL] * p[P_R_TH]
        state[S_TEMP] += (t_ss - state[S_TEMP]) * (1.0 - math.exp(-dt / p[P_TAU_TH]))
        x_free += p[P_DRIFT_UM_PER_K] * (state[S_TEMP] - p[P_T_AMB])
    state[S_XFREE] = x_free
    # rod stiffness + load mass + damping (semi-implicit Euler)
    mass = p[P_MOVING_MASS] + state[S_MASS]
    if p[P_ON_DYN] > 0.5:
        w2 = p[P_STIFF_N_PER_UM] * 1e6 / mass          # (rad/s)^2
        acc = -w2 * (state[S_X] - x_free) - 2.0 * p[P_ZETA] * math.sqrt(w2) * state[S_V]
        state[S_V] += dt * acc
        state[S_X] += dt * state[S_V]
        state[S_ACC] = acc
    else:
        state[S_X] = x_free
        state[S_V] = 0.0
        state[S_ACC] = 0.0
    # rod force: preload + weight of the load + spring + inertia of the load
    force = p[P_PRELOAD_N] + state[S_MASS] * G + p[P_SPRING_N_PER_UM] * state[S_X] \
        + state[S_MASS] * state[S_ACC] * 1e-6
    state[S_FORCE] = force
    state[S_SIGMA] = -force / p[P_ROD_AREA] * 1e-6
    state[S_T] += dt


@njit(cache=True)
def _record_history(state: np.ndarray, hist: np.ndarray) -> None:
    """Remember (time, position) after every sub-step, for the transport delay."""
    head = (int(state[S_HEAD]) + 1) % DELAY_BUFFER
    hist[0, head] = state[S_T]
    hist[1, head] = state[S_X]
    state[S_HEAD] = head
    if state[S_COUNT] < DELAY_BUFFER:
        state[S_COUNT] += 1.0


@njit(cache=True)
def _delayed_output(state: np.ndarray, p: np.ndarray, hist: np.ndarray) -> float:
    """The position `delay` seconds ago (zero-order hold on the sub-step history)."""
    if p[P_ON_DELAY] < 0.5:
        return state[S_X]
    head = int(state[S_HEAD])
    count = int(state[S_COUNT])
    target = state[S_T] - p[P_DELAY_S] + 1e-12
    idx = head
    for _ in range(count):
        if hist[0, idx] <= target:
            return hist[1, idx]
        idx = (idx - 1) % DELAY_BUFFER
    return hist[1, (head - count + 1) % DELAY_BUFFER]   # before the start: the oldest value


@njit(cache=True)
def _measure_all(state: np.ndarray, p: np.ndarray, rng: np.ndarray) -> None:
    noisy = p[P_ON_NOISE] > 0.5
    state[S_MEAS_X] = _measure(state[S_XOUT], p[P_NOISE_X], p[P_QUANT_X], rng, noisy)
    state[S_MEAS_I] = _measure(state[S_I], p[P_NOISE_I], p[P_QUANT_I], rng, noisy)
    state[S_MEAS_F] = _measure(state[S_FORCE], p[P_NOISE_F], p[P_QUANT_F], rng, noisy)
    state[S_MEAS_SIGMA] = -state[S_MEAS_F] / p[P_ROD_AREA] * 1e-6
    state[S_MEAS_T] = _measure(state[S_TEMP], p[P_NOISE_T], p[P_QUANT_T], rng, noisy)


@njit(cache=True)
def step_kernel(state: np.ndarray, p: np.ndarray, rng: np.ndarray, hist: np.ndarray,
                cmd: float, dt: float) -> None:
    """Advance the plant by dt under a held current command, then take the measurements."""
    if not (cmd == cmd):          # NaN command: the amplifier sees nothing, i.e. zero
        cmd = 0.0
    if cmd < p[P_I_MIN]:
        cmd = p[P_I_MIN]
    elif cmd > p[P_I_MAX]:
        cmd = p[P_I_MAX]
    state[S_CMD] = cmd
    if dt > 0.0:
        # Only the fast dynamics need short sub-steps: the magnetics follow the field path (rate-
        # independent, integrated in capped field increments) and the slow lags use exact exponentials.
        n = 1
        if p[P_ON_DYN] > 0.5 or p[P_ON_EDDY] > 0.5 or p[P_ON_AMP] > 0.5:
            n = int(math.ceil(dt / p[P_DT_SUB] - 1e-9))
            if n < 1:
                n = 1
        h = dt / n
        delayed = p[P_ON_DELAY] > 0.5
        for _ in range(n):
            _substep(state, p, cmd, h)
            if delayed:
                _record_history(state, hist)
    state[S_XOUT] = _delayed_output(state, p, hist)
    _measure_all(state, p, rng)


@njit(cache=True)
def run_kernel(state: np.ndarray, p: np.ndarray, rng: np.ndarray, hist: np.ndarray,
               time_s: np.ndarray, cmd: np.ndarray, mass: np.ndarray, out: np.ndarray) -> None:
    """Batch run: sample i is `step_kernel(cmd[i], time_s[i] - time_s[i-1])` (first dt = t1 - t0).

    out rows: displacement_um, current_A, stress_MPa, force_N, temperature_C (measured).
    """
    n = time_s.shape[0]
    for i in range(n):
        if i == 0:
            dt = time_s[1] - time_s[0] if n > 1 else 0.0
        else:
            dt = time_s[i] - time_s[i - 1]
        state[S_MASS] = mass[i]
        step_kernel(state, p, rng, hist, cmd[i], dt)
        out[0, i] = state[S_MEAS_X]
        out[1, i] = state[S_MEAS_I]
        out[2, i] = state[S_MEAS_SIGMA]
        out[3, i] = state[S_MEAS_F]
        out[4, i] = state[S_MEAS_T]
