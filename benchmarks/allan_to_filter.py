"""Allan analysis to a tuned filter, end to end, on a simulated sensor unlike the defaults.

Run: ``python benchmarks/allan_to_filter.py [--minutes 30]``. A gyroscope with ten times
the white noise and thirty times the bias random walk of the MEMS preset sits still for
``--minutes`` (003 III-B's procedure); ``allan_deviation`` + ``identify_noise`` +
``noise_densities`` give its noise densities, saved in a calibration file's ``noise``; then
a 5-minute random motion seen by the same sensor is estimated by every method whose noise
parameters the file sets (``margtrack run --calibration``'s path:
``Calibration.parameter_values``), once with the method's defaults and once with the
file's values. Prints the identified against the simulated densities and the error table
(total / heading / inclination RMSE, deg) for both.
"""

from __future__ import annotations

import argparse
import math

from margtrack import methods, sim
from margtrack.accuracy import error_series, summarize
from margtrack.calibration import Calibration, allan_deviation, identify_noise
from margtrack.calibration.allan import noise_densities
from margtrack.estimator.params import specs
from margtrack.sim.sensor_model import SensorErrors

RATE_HZ = 100.0


def sensor() -> dict[str, SensorErrors]:
    """A poor gyroscope (10x white noise, 30x bias walk of the MEMS preset), MEMS acc/mag."""
    base = SensorErrors.mems_gyr()
    gyr = SensorErrors(
        noise_density=10 * base.noise_density,
        bias=base.bias,
        bias_random_walk=30 * base.bias_random_walk,
        scale=base.scale,
        misalignment_deg=base.misalignment_deg,
        saturation=base.saturation,
    )
    return {"gyr_errors": gyr, "acc_errors": SensorErrors.mems_acc(),
            "mag_errors": SensorErrors.mems_mag()}


def identified(minutes: float, seed: int = 3) -> Calibration:
    """Noise densities of the sensor from a still recording, as a calibration file holds them."""
    still = sim.simulate(sim.trajectories.static(minutes * 60.0, RATE_HZ), seed=seed, **sensor())
    gyr = identify_noise(allan_deviation(still.gyr, RATE_HZ))
    acc = identify_noise(allan_deviation(still.acc, RATE_HZ))
    return Calibration(noise=noise_densities(gyr, acc), source="allan_to_filter")


def calibrated_methods() -> list[str]:
    """Registered methods with at least one parameter a calibration's noise sets."""
    return [
        name for name in methods.available()
        if any((s.calibrated_by or "").startswith("noise.")
               for s in specs(methods.get(name).params_type))
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0, help="still recording, min")
    args = parser.parse_args()
    cal = identified(args.minutes)
    truth = sensor()["gyr_errors"]
    nd = cal.noise
    print(f"gyro white noise: identified {nd.gyr_noise_density_rad_s_sqrt_hz:.3e}, simulated "
          f"{truth.noise_density:.3e} rad/s/sqrt(Hz)")
    print(f"gyro bias walk:   identified {nd.gyr_bias_walk_rad_s2_sqrt_hz:.3e}, simulated "
          f"{truth.bias_random_walk:.3e} rad/s/sqrt(s)")
    motion = sim.random_motion(300.0, RATE_HZ, 7, max_rate_deg_s=200.0, bandwidth_hz=2.0,
                               translation_m=0.02)
    rec = sim.simulate(motion, seed=7, **sensor())
    print("\n| method | parameters from the file | defaults: total / heading / incl. | "
          "file: total / heading / incl. |\n|---|---|---|---|")
    for name in calibrated_methods():
        values = cal.parameter_values(methods.get(name).params_type)
        row = []
        for params in ({}, values):
            est = methods.create(name, params).run(rec)
            err = summarize(error_series(est.quat, rec.quat_true, est.frame, rec.frame))
            row.append(f"{err.total_rmse_deg:.2f} / {err.heading_rmse_deg:.2f} / "
                       f"{err.inclination_rmse_deg:.2f}")
        told = ", ".join(f"{k}={v:.3g}" for k, v in values.items() if not math.isnan(v))
        print(f"| {name} | {told} | {row[0]} | {row[1]} |")


if __name__ == "__main__":
    main()
