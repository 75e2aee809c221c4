r"""A streaming prototype of the nuisance oracle (``bench_nuisance_oracle.py``): an information
filter on the payload and a set of nuisances, sample by sample, over the momentum windows.

Not in ``src/``: a measurement of what the streaming form would give and cost. Per sample it
evaluates the calibration's momentum terms and their Jacobian with respect to the free
nuisances (``compiled("momentum")``, one column, at the calibration's ``z``), keeps the last
2·25 + 1 in a ring, and for each complete window adds

.. math:: H \mathrel{+}= \sum_j w_j G_j^\top G_j, \qquad g \mathrel{+}= \sum_j w_j G_j^\top r_{0,j},
          \qquad G_j = [-\varphi_j,\ \partial r_j/\partial u], \qquad \hat\theta = -H^{-1}g,

:math:`\theta = (m, u)`, :math:`u` the nuisances whitened by the calibration's posterior
(:math:`\nu = \mu + Lu`, :math:`LL^\top = C`), :math:`H` starting from the prior
:math:`\mathrm{diag}(0, I)`. The residual is linear in :math:`m` and linearised in :math:`u`
at the calibration (the batch oracle's expanding form; relinearising moved the
whole-experiment payload by 0.02–0.09 kg median, at most 1.1 kg). The payload enters :math:`\partial r/\partial u` and the
rates' noise through :math:`m\,\partial\varphi/\partial u` and the momentum's gain: at a fixed
``m_lin`` (the batch check), or the filter's own current estimate (streaming).
``new_load(carry=True)`` marginalises the payload (Schur complement) and keeps what the load
told about the nuisances as prior for the next one (the ``session`` variants).

The weights are the batch oracle's (``--low-speed skip``: a window with a still sample is not
used; the calibration's window inflation; the bucket outside the covered angles not weighed).
q̈ (the IMU correction's) is the calibration's 0.3 s centred slope, given with each sample.

Usage (the cache of ``nuisance_oracle_prep.py``)::

    PYTHONPATH=src nice -n 5 python benchmarks/nuisance_filter.py --check --cells 1 --families nmpc
    PYTHONPATH=src nice -n 5 python benchmarks/nuisance_filter.py --variant imu --cells 1 0 2
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_nuisance_oracle import DT, whitening  # noqa: E402

from excavator_payload.estimators.classical.machine_calibration.data import balance_weights  # noqa: E402
from excavator_payload.estimators.classical.machine_calibration.settings import (  # noqa: E402
    BALANCE_HALF_WINDOW, BALANCE_RAMP, COVERAGE_JOINTS, HELD_SAMPLES, NO_LIMIT)
from excavator_payload.estimators.classical.machine_calibration.symbolic import compiled  # noqa: E402
from excavator_payload.estimators.classical.pressure_regression import ANGLES  # noqa: E402
from excavator_payload.model.codegen import column_map  # noqa: E402


class NuisanceFilter:
    """Payload and nuisances ``idx`` of ``cal`` (a MachineCalibration), streaming.

    Parameters
    ----------
    cal : MachineCalibration
        The calibrated and zeroed machine: prior mean ``z``, covariance, noise, inflation.
    idx : numpy.ndarray
        Indices in ``z`` of the nuisances re-estimated.
    m_lin : float or None
        Payload the Jacobian and weights are taken at (None: the current estimate, or half the
        rated payload until the payload is known to 50 kg).
    """

    def __init__(self, cal, idx: np.ndarray, m_lin: float | None = None):
        self.cal, self.idx, self.m_lin = cal, np.asarray(idx, int), m_lin
        self.L = whitening(cal, self.idx)
        self.n = len(self.idx)
        self.d = 1 + self.n
        w, u = balance_weights(BALANCE_HALF_WINDOW, BALANCE_RAMP)
        self.wb, self.ub = w, u
        self.W = float(w.sum()) * DT
        self.len = 2 * BALANCE_HALF_WINDOW + 1
        self.lever_var = (cal._head**2 + cal._rod**2) * (cal.pressure_std**2 + 1.0)
        self.rated = float(cal.arm.machine.rated_payload)
        off = cal.offset_vector()
        self.low = np.full(3, -NO_LIMIT)
        self.high = np.full(3, NO_LIMIT)
        for j in range(3):
            if COVERAGE_JOINTS[j] and cal.angle_coverage[j, 0] > -NO_LIMIT / 2:
                self.low[j], self.high[j] = cal.angle_coverage[j] + off[ANGLES[j]]
        self._f = column_map(compiled("momentum"), 1)
        self.carried = (np.zeros((self.n, self.n)), np.zeros(self.n))
        self.new_load(carry=False)

    def new_load(self, carry: bool = True) -> None:
        """Start a new load: the payload unknown again; with ``carry`` the nuisances keep what
        the loads so far told about them (the payload marginalised), else the calibration's
        posterior alone."""
        if carry and self.S[0, 0] > 0:
            H, g = self.normal_equations(self.solve()[0])
            A = H[1:, 1:] - np.outer(H[1:, 0], H[0, 1:]) / H[0, 0]
            b = g[1:] - H[1:, 0] * g[0] / H[0, 0]
            self.carried = (self.carried[0] + A, self.carried[1] + b)
        elif not carry:
            self.carried = (np.zeros((self.n, self.n)), np.zeros(self.n))
        # sufficient statistics of a = [-φ, ∂r0/∂u, ∂φ/∂u] (1 + 2n): the residual's Jacobian in u
        # is ∂r0/∂u - m ∂φ/∂u, so that H and g at any linearisation payload follow from them
        self.S = np.zeros((1 + 2 * self.n, 1 + 2 * self.n))
        self.t = np.zeros(1 + 2 * self.n)
        self._ring = []
        self._run = None
        self._sign = np.zeros(3)
        self._age = np.zeros(3, int)
        self.windows = 0

    def _prior(self):
        P = np.eye(self.d)
        P[0, 0] = 1e-12
        P[1:, 1:] += self.carried[0]
        b = np.r_[0.0, self.carried[1]]
        return P, b

    def normal_equations(self, m: float) -> tuple[np.ndarray, np.ndarray]:
        """The windows' H and g with the Jacobian in u taken at payload ``m``."""
        n = self.n
        T = np.zeros((1 + 2 * n, 1 + n))
        T[0, 0] = 1.0
        T[1:1 + n, 1:] = np.eye(n)
        T[1 + n:, 1:] = -m * np.eye(n)
        return T.T @ self.S @ T, T.T @ self.t

    @property
    def H_data(self) -> np.ndarray:
        return self.normal_equations(self._linearisation_payload())[0]

    def solve(self, iterations: int = 3) -> tuple[float, float, np.ndarray]:
        """(payload, its std, the nuisances ν) from the windows so far; the Jacobian in u at
        ``m_lin``, or (None) at the payload it gives, by fixed-point iteration from the last."""
        P, b = self._prior()
        m = self.m_lin if self.m_lin is not None else getattr(self, "_last", 0.5 * self.rated)
        for _ in range(1 if self.m_lin is not None else iterations):
            Hd, gd = self.normal_equations(m)
            H = Hd + P
            theta = -np.linalg.solve(H, gd + b)
            m = float(theta[0])
        if self.m_lin is None and Hd[0, 0] > 1.0 / 50.0**2:
            self._last = m
        var = np.linalg.solve(H, np.eye(self.d)[:, 0])[0]
        nu = self.cal.z[self.idx] + self.L @ theta[1:]
        return float(theta[0]), math.sqrt(max(var, 0.0)), nu

    def _linearisation_payload(self) -> float:
        """The payload of the rates' noise through the momentum (the windows' weights)."""
        if self.m_lin is not None:
            return self.m_lin
        return getattr(self, "_last", 0.5 * self.rated)

    def update(self, values: np.ndarray, qdd: np.ndarray, run) -> bool:
        """One valid sample (values of the sensor set, q̈ (4), its run id: a new id where a
        sample was dropped). True when a window was added."""
        cal = self.cal
        if run != self._run:  # a new run: no window spans the gap, the friction's state unknown
            self._ring, self._run = [], run
            self._sign[:], self._age[:] = 0.0, 0
            first = True
        else:
            first = False
        speed_file = cal.rod_speeds(values[None, :])[0]
        sliding = np.abs(speed_file) > cal._stribeck
        # held_direction, causally: the last sliding sign held through HELD_SAMPLES slower ones
        self._age = np.where(sliding, 0, self._age + (0 if first else 1))
        self._sign = np.where(sliding, np.sign(speed_file), self._sign)
        sign = np.where(self._age > HELD_SAMPLES, 0.0, self._sign)
        out = self._f(values[:, None], np.asarray(qdd, float)[:, None], cal.p_file, cal.z, sign[:, None])
        A, dA, lever, speed, stiction, dP0, dPm, igain = out
        m_lin = self._linearisation_payload()
        dA = dA.reshape(12, len(cal.z))[:, self.idx] @ self.L  # (12, n) whitened
        dP = dP0.reshape(3, 4) + m_lin * dPm.reshape(3, 4)
        inside = (values[list(ANGLES)] >= self.low) & (values[list(ANGLES)] <= self.high)
        self._ring.append((A[:, 0], dA, lever[:, 0], speed[:, 0], np.sum(dP**2, axis=1), igain[:, 0], inside))
        if len(self._ring) > self.len:
            self._ring.pop(0)
        if len(self._ring) < self.len:
            return False
        self._window()
        return True

    def _window(self) -> None:
        cal = self.cal
        A = np.array([s[0] for s in self._ring])  # (51, 12)
        dA = np.array([s[1] for s in self._ring])  # (51, 12, n)
        wdt, u = self.wb * DT, self.ub
        integ, mom = wdt @ A[:, 6:12], u @ A[:, 0:6]
        r0 = (integ[0:3] - mom[0:3]) / self.W
        sens = (mom[3:6] - integ[3:6]) / self.W
        dinteg, dmom = np.einsum("k,kan->an", wdt, dA[:, 6:12]), np.einsum("k,kan->an", u, dA[:, 0:6])
        dr0 = (dinteg[0:3] - dmom[0:3]) / self.W
        dsens = (dmom[3:6] - dinteg[3:6]) / self.W
        G = np.concatenate([-sens[:, None], dr0, dsens], axis=1)  # (3, 1 + 2n)
        # weights: the batch oracle's "skip" rule (evaluate_windows + weights)
        lever = self._ring[BALANCE_HALF_WINDOW][2]
        speeds = np.array([s[3] for s in self._ring])
        still = np.any(np.abs(speeds) < cal._still_speed, axis=0)
        gain = np.array([s[4] for s in self._ring])
        igain = np.array([s[5] for s in self._ring])
        integrand_var = (self.wb @ igain) / self.wb.sum() * cal.rate_var
        end_var = ((u**2) @ gain) / (self.wb.sum() * DT) ** 2 * cal.rate_var
        var = lever**2 * self.lever_var + integrand_var + end_var
        w = np.where(still, 0.0, 1.0 / var) / cal.window_inflation
        inside = np.all(np.array([s[6] for s in self._ring]), axis=0)
        ok = inside & np.isfinite(w) & np.isfinite(r0) & np.all(np.isfinite(G), axis=1)
        w = np.where(ok, w, 0.0)
        G = np.where(ok[:, None], G, 0.0)
        r0 = np.where(ok, r0, 0.0)
        self.S += np.einsum("ja,j,jb->ab", G, w, G)
        self.t += np.einsum("ja,j,j->a", G, w, r0)
        self.windows += 1


def run_experiment(filt: NuisanceFilter, ds_e, times_out: np.ndarray | None = None):
    """Feed one experiment's valid samples (the batch's rows, q̈ and runs); returns the
    estimates (payload, std) at ``times_out`` (the state after the last sample at or before)."""
    from bench_nuisance_oracle import valid_rows

    values, qdd, runs, times = valid_rows(ds_e, filt.cal.arm.machine)
    out = []
    k = 0
    times_out = np.zeros(0) if times_out is None else np.asarray(times_out, float)
    for i in range(len(values)):
        filt.update(values[i], qdd[i], runs[i])
        while k < len(times_out) and (i + 1 == len(values) or times[i + 1] > times_out[k]):
            out.append(filt.solve()[:2] if filt.S[0, 0] > 0 else (math.nan, math.nan))
            k += 1
    while k < len(times_out):
        out.append(filt.solve()[:2])
        k += 1
    return np.array(out).reshape(-1, 2)


def main() -> None:
    """The check (the filter with the batch's linearisation payload ends where the batch
    oracle's expanding form ends) and the streaming filter judged like the benchmark."""
    import argparse
    import time

    import pandas as pd
    from bench_nuisance_oracle import IMU, LOOK_AHEAD, OFFSETS, VARIANTS, oracle
    from nuisance_oracle_prep import CELLS, cached, estimator, family

    from excavator_payload.data.dataset import Dataset

    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", type=Path, default=Path("/tmp/oracle_cache"))
    ap.add_argument("--n-test", type=int, default=8)
    ap.add_argument("--cells", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--families", nargs="+", default=["nmpc", "lever"])
    ap.add_argument("--check", action="store_true", help="only the check against the batch oracle")
    ap.add_argument("--variant", default="offsets+imu", choices=("offsets+imu", "imu", "offsets"),
                    help="the nuisances re-estimated (the batch oracle's variant of that name)")
    a = ap.parse_args()
    idx = {"offsets+imu": np.r_[OFFSETS, IMU], "imu": IMU, "offsets": OFFSETS}[a.variant]
    assert np.array_equal(VARIANTS[a.variant][0], idx)
    rows = []
    for c in a.cells:
        est = estimator(a.cache, *CELLS[c])
        cal = est.calibration
        # the kernel's estimate at t rests on windows ending its differentiator's half window and
        # the outlier gate's look-ahead before t; the filter adds a window at its last sample
        delay = (est.options["half_window"] + LOOK_AHEAD) * DT
        for fam in a.families:
            ds = cached(a.cache, f"family_{fam}_{a.n_test}", lambda: family(fam, a.n_test, 9100))
            frame = est.estimate(ds)
            f = ds.frame
            session = NuisanceFilter(cal, idx)
            for e in f["experiment"].unique():
                sel = (f["experiment"] == e).to_numpy()
                ds_e = Dataset(f[sel].reset_index(drop=True), ds.meta)
                truth = float(f.loc[sel, "payload"].iloc[0])
                t = f.loc[sel, "time"].to_numpy(float)
                fe = frame[sel].reset_index(drop=True)
                pe = fe["payload_estimate"].to_numpy(float)
                judged = (t - t[0] >= 1.0) & (fe["status"].astype(str).to_numpy() == "ok") & np.isfinite(pe)
                m0 = pe[judged][-1]
                if a.check:
                    t0 = time.time()
                    fixed = NuisanceFilter(cal, idx, m_lin=m0)
                    end = run_experiment(fixed, ds_e, t[-1:])[-1]
                    spent = time.time() - t0
                    batch = oracle(cal, ds_e, m0, t[-1:], 0.0)[a.variant]["early"][-1]
                    print(f"{CELLS[c][0]} / {fam} / experiment {e}: streaming {end[0]:.6f} kg (std {end[1]:.6f}),"
                          f" batch expanding {batch[0]:.6f} kg (std {batch[1]:.6f}); "
                          f"{fixed.windows} windows, {1e3 * spent / sel.sum():.2f} ms per sample (Python)",
                          flush=True)
                    continue
                at = t[judged] - delay
                own = run_experiment(NuisanceFilter(cal, idx), ds_e, at)
                session.new_load(carry=True)
                carried = run_experiment(session, ds_e, at)
                for name, est_t in (("streaming kernel", pe[judged]), ("filter", own[:, 0]),
                                    ("filter (session)", carried[:, 0])):
                    err = est_t - truth
                    err = err[np.isfinite(err)]
                    rows.append({"calibration": CELLS[c][0], "zero": CELLS[c][1], "family": fam, "experiment": e,
                                 "method": name, "max": float(np.max(np.abs(err))),
                                 "rms": float(np.sqrt(np.mean(err**2))), "final": float(abs(err[-1]))})
            if rows:
                table = pd.DataFrame(rows)
                g = table[(table.calibration == CELLS[c][0]) & (table.family == fam)].groupby("method", sort=False)
                s = g.agg(mean_max=("max", "mean"), mean_rms=("rms", "mean"), mean_final=("final", "mean"))
                s["within_1pct"] = g["max"].apply(lambda x: float(np.mean(x <= 50.0)))
                print(f"\n{CELLS[c][0]} / {CELLS[c][1]} / {fam} ({a.variant})")
                print(s.to_string(float_format=lambda v: f"{v:.2f}"), flush=True)


if __name__ == "__main__":
    main()
