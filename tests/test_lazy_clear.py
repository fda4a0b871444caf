"""A ``paper`` sender builds its clear message only when asked, and sends the same bytes as before."""

import numpy as np

import roadcollab as rc
from roadcollab.privacy.obfuscation import obfuscate
from roadcollab.wire import protocol


def test_lazy_clear_message_and_identical_obfuscation():
    cfg = rc.ExperimentConfig(n_vehicles=2, n_runs=1, segment_length=60.0)
    pipe = rc.FleetPipeline(cfg, rc.sample_fleet(2, cfg.fleet, rng=1))
    w = pipe.road(np.random.default_rng(0)).velocity[:pipe.grid.n_samples]
    ys = rc.simulate_measurements(pipe.estimators, w, 0.05, rng=2)
    steps = rc.Relay(pipe.estimators, rc.Exchange("paper", cfg.obfuscation), rng=3, unguarded=True).run(ys)
    step = steps[0]
    assert "clear" not in step.__dict__                  # not built by the relay
    clear = step.clear
    assert clear.mechanism == "none" and step.clear is clear
    # The message the library sent equals obfuscate() of the clear message with the same generator.
    rng = np.random.default_rng(3)
    again, _, _ = obfuscate(clear, pipe.grid, cfg.obfuscation, rng=rng, spectra=(step.result.E, step.result.Wf))
    assert protocol.encode(again) == protocol.encode(step.message)
