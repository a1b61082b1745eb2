"""The offline estimators on simulated disturbances stronger than the shared BROAD trials'.

Run ``python benchmarks/smoother_disturbances.py [--seeds 3] [--param tau_acc_s=4.5 ...]``.

60 s of ``sim.random_motion`` (up to 200 deg/s, 1 Hz band) seen by the consumer-MEMS error
presets, ENU, one seed per repetition, with one disturbance at a time at several
strengths: linear acceleration (translation of peak amplitude 0.02-0.5 m in the same
band: up to several g at 0.5 m), a limb swinging at 1 Hz about a joint (30 deg with the
sensor 0.4 m from it, 60 deg at 0.6 m: an acceleration that turns with the sensor), a
magnet passing (a 10 s Hann bump of 20-200 µT along
east, a 50 µT earth field), and a gyro bias of 0.5-2 deg/s. Printed per case: total
RMSE (deg) of ``robust``, ``smoother`` and, when vqf is installed,
VQF and offline VQF, mean over the seeds. ``--param name=value`` (repeatable) adds a
column: the smoother with those parameters.
"""

from __future__ import annotations

import argparse
import importlib.util

import numpy as np

from margtrack import registry, sim
from margtrack.bench.runner import Adapter, score

METHODS = ("robust", "smoother")


def _cases(seed: int):
    def motion(translation_m: float = 0.0):
        return sim.random_motion(60.0, 100.0, seed, max_rate_deg_s=200.0, bandwidth_hz=1.0,
                                 translation_m=translation_m)

    errors = {"gyr_errors": sim.SensorErrors(noise_density=np.radians(0.01),
                                             bias=np.radians([0.2, -0.1, 0.15]))}
    for amplitude in (0.02, 0.1, 0.5):
        yield f"translation {amplitude} m", sim.simulate(motion(amplitude), seed=seed, **errors)
    for amplitude_deg, length_m in ((30.0, 0.4), (60.0, 0.6)):
        # a limb's sensor: its linear acceleration turns with the limb (not zero-mean in
        # the body frame as random translation is)
        swing = sim.limb_swing(60.0, 100.0, amplitude_deg, 1.0, length_m)
        yield (f"limb swing {amplitude_deg:g} deg {length_m:g} m",
               sim.simulate(swing, seed=seed, **errors))
    for peak in (20.0, 60.0, 200.0):
        pass_ = sim.magnet_pass(30.0, 10.0, peak, (1.0, 0.0, 0.0))
        yield f"magnet pass {peak:g} uT", sim.simulate(motion(), seed=seed,
                                                      mag_disturbances=[pass_], **errors)
    for bias in (0.5, 2.0):
        rec = sim.simulate(motion(), seed=seed, gyr_errors=sim.SensorErrors(
            noise_density=np.radians(0.01), bias=np.radians([bias, -bias, bias])))
        yield f"gyro bias {bias:g} deg/s", rec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--param", "-p", action="append", default=[],
                        help="name=value: a column of the smoother with these parameters")
    args = parser.parse_args()
    methods = {name: registry.create(name) for name in METHODS}
    if args.param:
        params = registry.parse_params_items(args.param)
        methods["smoother " + ",".join(args.param)] = registry.create("smoother", params)
    if importlib.util.find_spec("vqf") is not None:
        from margtrack.bench import external

        methods["vqf"] = Adapter(external.run_vqf, "vqf")
        methods["vqf-offline"] = Adapter(external.run_vqf_offline, "vqf-offline")
    table: dict[str, dict[str, list[float]]] = {}
    for seed in range(args.seeds):
        for case, rec in _cases(seed):
            for name, method in methods.items():
                method.reset()
                est = method.run(rec)
                err = score(rec, est.quat, est.frame).errors.total_rmse_deg
                table.setdefault(case, {}).setdefault(name, []).append(err)
    width = max(15, *(len(n) + 2 for n in methods))
    print(f"{'case':24s}" + "".join(f"{n:>{width}s}" for n in methods))
    for case, row in table.items():
        print(f"{case:24s}" + "".join(f"{np.mean(row[n]):{width}.2f}" for n in methods))


if __name__ == "__main__":
    main()
