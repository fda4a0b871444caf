"""A lane driven twice by one drive (docs/map.md, Limits): each visit is a pass of its own, and a store row's
``n_vehicles`` counts passes, not distinct vehicles; the votes of an anomaly count passes too."""

import numpy as np

from roadcollab.experiments.drives.city import city_network
from roadcollab.experiments.drives.mixed_fleet import simulate_drive
from roadcollab.experiments.drives.road_survey import lane_survey
from roadcollab.geo.matching import RoadPass
from roadcollab.models.anomaly import Anomaly
from roadcollab.models.profile import RoadProfile
from roadcollab.models.road import RoadSpec, generate_road
from roadcollab.models.vehicle import FleetSpec, sample_fleet


def _drive():
    base = generate_road(RoadSpec(length=360.0, iso_class="B", anomaly_density=0.0), rng=np.random.default_rng(4))
    hole = Anomaly(149.7, "both", "pothole", 0.05, 0.6)
    d = np.asarray(base.distance)
    bump = np.column_stack([hole.elevation(d)] * 2)
    road = RoadProfile(d, base.elevation + bump, (hole,), "test")
    (vehicle,) = sample_fleet(1, FleetSpec(), rng=np.random.default_rng(5))
    return simulate_drive(road, vehicle, 15.0, start=0.0, end_margin=20.0, sample_rate=100.0,
                          rng=np.random.default_rng(6))


def test_one_drive_on_a_lane_twice_counts_as_two_passes():
    net = city_network()                                 # main: 600 m; the drive covers its measures 0-340
    drive = _drive()
    one = RoadPass("main", 1, drive, 60, 0.2, (0.0, float(drive.positions[-1])))
    seg1, an1, _ = lane_survey([one], net, bootstrap=0)
    seg2, an2, _ = lane_survey([one, one], net, bootstrap=0)
    assert [s.from_m for s in seg1] == [s.from_m for s in seg2] == [100.0, 200.0]
    assert all(s.n_vehicles == 1 for s in seg1) and all(s.n_vehicles == 2 for s in seg2)
    # the same record twice fuses to itself: the IRI does not change, only the count
    for a, b in zip(seg1, seg2):
        assert abs(b.iri_m_per_km / a.iri_m_per_km - 1) < 1e-9
    pot1 = [a for a in an1 if a.kind == "pothole"]
    pot2 = [a for a in an2 if a.kind == "pothole"]
    assert len(pot1) == len(pot2) == 1 and abs(pot1[0].measure_m - 150.0) <= 2.0
    assert pot1[0].votes == 1 and pot2[0].votes == 2
