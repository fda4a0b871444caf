"""How low `paper` could go if parts of it cost nothing: a lower bound for the bench's 2 ms target.

One vehicle-segment as `roadcollab bench` times it (decode to encode), on the same segments, in four
variants run back to back in alternating order:
  full                           the library as it is (fresh receiver caches: T~, S~ are new);
  free_receiver                  T~ and S~ decoded, certified and evaluated untimed beforehand, so the
                                 timed decode and learn hit the receiver's caches;
  free_receiver_and_sender_cert  the same, and the sender's stability certificates cost nothing;
  none                           the plain exchange, for scale (the VM's speed moves by up to 1.7x).
Usage: .venv/bin/python tools/paper_floor.py   (from the repository root)
"""
import time, statistics
import numpy as np
from threadpoolctl import threadpool_limits
from roadcollab.experiments.bench.study import _config_for
from roadcollab.experiments.pipeline import FleetPipeline
from roadcollab.collaboration.relay import Exchange, Relay
from roadcollab.models.simulation import add_sensor_noise, simulate_response
from roadcollab.models.vehicle import sample_fleet
from roadcollab.wire import protocol
from roadcollab.lti import realisation as rl
from roadcollab.lti.response import FrequencyResponseCache
cfg = _config_for(4000); rng = np.random.default_rng(0)
fleet = sample_fleet(2, cfg.fleet, rng=rng); pipe = FleetPipeline(cfg, fleet)
prev, car = pipe.estimators; grid = pipe.grid
om = grid.omega_dt[grid.active_index]
relay = Relay(pipe.estimators, Exchange("paper", cfg.obfuscation), rng=rng)
real_cert = rl.StateSpaceData._certify
res = {"full": [], "free_receiver": [], "free_receiver_and_sender_cert": [], "none": []}
relay_none = Relay(pipe.estimators, "none", rng=1)
none_caches = (rl.SystemCache(), FrequencyResponseCache())
with threadpool_limits(1):
    for k in range(62):
        w = pipe.road(rng).velocity[:grid.n_samples]
        y_prev = add_sensor_noise(simulate_response(prev.true_plant, w), cfg.sensor_noise_std, rng=rng)
        r_prev = prev.estimate(y_prev)
        incoming = protocol.encode(relay.send(0, r_prev).message)
        incoming_none = protocol.encode(relay_none.send(0, r_prev).message)
        y = add_sensor_noise(simulate_response(car.true_plant, w), cfg.sensor_noise_std, rng=rng)
        order = list(res) if k % 2 else list(res)[::-1]
        for variant in order:
            if variant == "none":
                car.system_cache, car.response_cache = none_caches
                t0 = time.perf_counter()
                msg_in = protocol.decode(incoming_none, systems=car.system_cache)
                protocol.encode(relay_none.send(1, car.estimate(y, msg_in), msg_in).message)
                if k > 1:
                    res[variant].append(1e3 * (time.perf_counter() - t0))
                continue
            car.system_cache, car.response_cache = rl.SystemCache(), FrequencyResponseCache()
            if variant != "full":   # untimed: decode, certify and evaluate the incoming systems into the receiver's caches
                m = protocol.decode(incoming, systems=car.system_cache)
                car.response_cache.response(m.S, om); car.response_cache.response(m.T, om, inverse=True)
            if variant == "free_receiver_and_sender_cert":
                rl.StateSpaceData._certify = lambda self: (0.5, 1.0)
            t0 = time.perf_counter()
            msg_in = protocol.decode(incoming, systems=car.system_cache)
            r = car.estimate(y, msg_in)
            protocol.encode(relay.send(1, r, msg_in).message)
            dt = time.perf_counter() - t0
            rl.StateSpaceData._certify = real_cert
            if k > 1:
                res[variant].append(1e3 * dt)
for v, t in res.items():
    print(f"{v:32s} min {min(t):.2f} median {statistics.median(t):.2f} ms")
