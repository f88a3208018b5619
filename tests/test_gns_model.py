import pytest
import torch
from torch import nn

from runout.errors import InputError
from runout.gns.checkpoint import load_simulator, save_checkpoint
from runout.gns.checkpoint_checks import check_schema
from runout.gns.features import Constraints
from runout.gns.fine_tuning import renormalise, widen_material_features
from runout.gns.network import EdgeUpdate
from runout.gns.rollout import CHECK_EVERY, MIN_FRAMES_BEFORE_STOP, RolloutDiverged, rollout
from runout.gns.schema import FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.gns.training import corrected_target, masked_loss, random_walk_noise

torch.set_num_threads(1)  # tiny graphs: extra threads only add OpenMP synchronisation cost

TINY = NetworkConfig(latent=16, hidden=16, hidden_layers=2, message_passing_steps=2)
STATS = Normalisation((0.0, -0.01), (0.02, 0.03), (0.0, -1e-3), (2e-3, 3e-3), 2.5e-3)
BOUNDS = torch.tensor([[0.0, 40.0], [0.0, 20.0]])


def tiny_simulator(materials=("tan_phi",), seed=0) -> GraphNetworkSimulator:
    torch.manual_seed(seed)
    return GraphNetworkSimulator(FeatureSchema(material_features=materials), STATS, 4.6, TINY).eval()


def heap(n_steps_history=6):
    """A little heap of 30 soil points on 10 ground points, drifting right: [6, N, 2]."""
    soil = torch.stack(torch.meshgrid(torch.arange(6.0), torch.arange(5.0), indexing="ij"), -1).reshape(-1, 2) * 2
    soil = soil + torch.tensor([10.0, 4.0])
    ground = torch.stack([torch.arange(10.0) * 2 + 8, torch.full((10,), 2.0)], -1)
    x0 = torch.cat([ground, soil])
    drift = torch.cat([torch.zeros(10), torch.full((30,), 0.05)])
    frames = torch.stack([x0 + torch.stack([drift * t, torch.zeros(40)], -1) for t in range(n_steps_history)])
    ptype = torch.cat([torch.full((10,), 3), torch.full((30,), 6)])
    return frames, ptype


def test_noise_is_a_random_walk_with_the_stated_velocity_std():
    sigma = 0.067 * 0.0375  # m/frame: 0.067 m/s x 0.0375 s
    window = torch.zeros((200_000, 6, 2))
    movable = torch.ones(200_000, dtype=torch.bool)
    movable[:1000] = False
    noise = random_walk_noise(window, sigma, movable, torch.Generator().manual_seed(0))
    velocity = noise[1000:, 1:] - noise[1000:, :-1]
    increments = velocity[:, 1:] - velocity[:, :-1]
    assert noise[:, 0].abs().max() == 0 and noise[:1000].abs().max() == 0
    assert velocity[:, -1].std().item() == pytest.approx(sigma, rel=0.01)
    assert increments.std().item() == pytest.approx(sigma / 5**0.5, rel=0.01)
    assert velocity.mean().abs().item() < 1e-5


def test_corrected_target_restores_the_true_next_velocity():
    frames, ptype = heap(7)
    window, true_next = frames[:6].transpose(0, 1), frames[6]
    noise = random_walk_noise(window, 0.05, ptype != 3, torch.Generator().manual_seed(3))
    noisy = window + noise
    a = corrected_target(noisy, true_next, noise)
    updated = noisy[:, -1] + (noisy[:, -1] - noisy[:, -2]) + a  # the simulator's update
    torch.testing.assert_close(updated - noise[:, -1], true_next)  # true next position
    torch.testing.assert_close(updated - noisy[:, -1], true_next - window[:, -1])  # true next velocity


def test_split_first_edge_layer_equals_the_concatenated_layer():
    torch.manual_seed(0)
    edge = EdgeUpdate(latent=8, hidden=8, hidden_layers=2)
    v, e = torch.randn(5, 8), torch.randn(7, 8)
    s, r = torch.tensor([0, 1, 2, 3, 4, 0, 2]), torch.tensor([1, 1, 0, 4, 3, 2, 2])
    w_s, w_r = edge.project_nodes.weight.chunk(2, dim=0)
    b_s, b_r = edge.project_nodes.bias.chunk(2)
    concat = nn.Linear(24, 8)
    with torch.no_grad():
        concat.weight.copy_(torch.cat([w_s, w_r, edge.project_edges.weight], dim=1))
        concat.bias.copy_(b_s + b_r)
    expected = edge.rest(concat(torch.cat([v[s], v[r], e], dim=1)))
    torch.testing.assert_close(edge(v, e, s, r), expected)


def test_widened_model_predicts_exactly_what_the_base_predicted():
    frames, ptype = heap()
    base = tiny_simulator(("tan_phi",))
    tan_phi = torch.full((40, 1), 0.6)
    with torch.no_grad():
        before = base.next_positions(frames.transpose(0, 1), ptype, tan_phi, BOUNDS)
        widened = widen_material_features(base, ("tan_phi", "c_over_100kPa"))
        cohesion = torch.rand((40, 1))
        after = widened.next_positions(frames.transpose(0, 1), ptype, torch.cat([tan_phi, cohesion], 1), BOUNDS)
    assert widened.schema.material_width == 2
    assert torch.equal(before, after)


def test_widening_refuses_a_list_that_does_not_extend_the_old_one():
    with pytest.raises(InputError, match="must start with the old one"):
        widen_material_features(tiny_simulator(("tan_phi",)), ("c_over_100kPa",))


def test_schema_mismatch_names_the_difference_in_one_sentence():
    sim = tiny_simulator(("tan_phi",))
    data = FeatureSchema(material_features=("tan_phi", "c_over_100kPa"))
    with pytest.raises(InputError) as err:
        check_schema(sim, data, "base.pt", "data/train.npz")
    message = str(err.value)
    assert "material_features is [tan_phi] in the model but [tan_phi, c_over_100kPa] in the data" in message
    assert message.count(". ") == 0 and message.endswith(".")


def test_checkpoint_round_trip_keeps_predictions_and_schema(tmp_path):
    frames, ptype = heap()
    sim = tiny_simulator(("tan_phi", "c_over_100kPa"))
    material = torch.rand((40, 2))
    save_checkpoint(tmp_path / "m.pt", sim, step=7)
    loaded = load_simulator(tmp_path / "m.pt")
    assert loaded.schema == sim.schema and not loaded.training
    with torch.no_grad():
        args = (frames.transpose(0, 1), ptype, material, BOUNDS)
        assert torch.equal(sim.next_positions(*args), loaded.next_positions(*args))


def test_a_file_that_is_no_checkpoint_is_a_one_line_input_error(tmp_path):
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="junk.pt: not a readable PyTorch checkpoint"):
        load_simulator(tmp_path / "junk.pt")
    torch.save({"format": "other"}, tmp_path / "other.pt")
    with pytest.raises(InputError, match="expected a runout GNS checkpoint"):
        load_simulator(tmp_path / "other.pt")


def test_rollout_keeps_kinematic_points_and_stays_in_the_domain():
    frames, ptype = heap()
    frames[:, 10:, 0] += 15.0  # heap near the right wall, drifting into it
    sim = tiny_simulator()
    with torch.no_grad():
        out = rollout(sim, frames, ptype, torch.full((40, 1), 0.5), 25, BOUNDS)
    assert out.shape == (31, 40, 2)
    assert torch.equal(out[:, :10], frames[:1, :10].expand(31, -1, -1))
    assert (out[..., 0] >= 0).all() and (out[..., 0] <= 40).all()
    assert (out[..., 1] >= 0).all() and (out[..., 1] <= 20).all()


def test_a_nan_stops_the_rollout_with_a_clear_error():
    frames, ptype = heap()
    sim = tiny_simulator()
    with torch.no_grad():
        sim.network.decoder[-1].bias.fill_(float("nan"))
        with pytest.raises(RolloutDiverged, match="non-finite positions by step 10"):
            rollout(sim, frames, ptype, torch.full((40, 1), 0.5), 30, BOUNDS)


def test_checkpointed_rollout_gives_the_same_gradient_as_a_plain_one():
    frames, ptype = heap()
    sim = tiny_simulator()
    grads = []
    for checkpoint in (False, True):
        material = torch.full((40, 1), 0.5, requires_grad=True)
        out = rollout(sim, frames, ptype, material, 12, BOUNDS, checkpoint=checkpoint)
        out[-1, 10:, 0].sum().backward()
        grads.append(material.grad)
    assert grads[0].abs().sum() > 0
    torch.testing.assert_close(grads[0], grads[1])


def test_rollout_stops_when_the_flow_stops():
    frames, ptype = heap()
    sim = tiny_simulator()
    with torch.no_grad():
        sim.network.decoder[-1].weight.zero_()
        sim.network.decoder[-1].bias.copy_(-sim.acc_mean / sim.acc_scale)  # zero acceleration
        still = frames[-1:].expand(6, -1, -1)
        out = rollout(sim, still, ptype, torch.full((40, 1), 0.5), 200, BOUNDS, stop_speed=1e-4)
    assert MIN_FRAMES_BEFORE_STOP <= out.shape[0] < MIN_FRAMES_BEFORE_STOP + 2 * CHECK_EVERY


def test_blocked_inference_equals_the_differentiable_forward(monkeypatch):
    import runout.gns.network as network

    monkeypatch.setattr(network, "EDGE_BLOCK", 7)  # force many blocks
    frames, ptype = heap()
    sim = tiny_simulator()
    args = (frames.transpose(0, 1), ptype, torch.full((40, 1), 0.5), BOUNDS)
    with torch.no_grad():
        blocked = sim(*args)
    torch.testing.assert_close(blocked, sim(*args).detach())


def test_the_case_holds_kinematic_points_and_keeps_the_rest_inside_the_walls():

    constraints = Constraints.of(torch.tensor([6, 3, 6]), [[0.0, 10.0], [0.0, 5.0]])
    current = torch.tensor([[1.0, 1.0], [2.0, 0.5], [9.0, 4.0]])
    predicted = torch.tensor([[-1.0, 2.0], [3.0, 3.0], [12.0, 6.0]])
    out = constraints.constrain(predicted, current)
    assert torch.equal(out, torch.tensor([[0.0, 2.0], [2.0, 0.5], [10.0, 5.0]]))


def test_the_loss_is_a_weighted_mean_over_the_points_that_move():
    constraints = Constraints.of(torch.tensor([6, 6, 3]), [[0.0, 10.0], [0.0, 10.0]])  # the third point is kinematic: no loss
    weights = torch.tensor([1.0, 4.0, 1.0])
    predicted, target = torch.zeros((3, 2)), torch.tensor([[1.0, 0.0], [2.0, 0.0], [5.0, 0.0]])
    assert masked_loss(predicted, target, constraints, weights).item() == pytest.approx((1.0 + 4.0 * 4.0) / 5.0)
    assert masked_loss(predicted, target, constraints).item() == pytest.approx((1.0 + 4.0) / 2.0)


def test_held_positions_of_the_scene_at_rest_get_no_noise():
    window = torch.zeros((4000, 6, 2))
    held = torch.tensor([6, 4, 1, 0]).repeat_interleave(1000)
    noise = random_walk_noise(window, 0.1, torch.ones(4000, dtype=torch.bool), torch.Generator().manual_seed(0), held)
    assert torch.all(noise[:1000] == 0)  # all six held: the rollout's very first step
    assert torch.all(noise[1000:2000, :4] == 0) and torch.all(noise[1000:2000, 4:] != 0)
    velocity = noise[1000:2000, -1] - noise[1000:2000, -2]  # two increments of std 0.1 / sqrt(5) since the rest
    assert velocity.std().item() == pytest.approx(0.1 * (2 / 5) ** 0.5, rel=0.1)
    assert torch.equal(noise[2000:3000] != 0, noise[3000:] != 0)  # held 1 = the first position, never noised
    last = noise[3000:, -1] - noise[3000:, -2]
    assert last.std().item() == pytest.approx(0.1, rel=0.1)


def test_a_window_knows_how_many_of_its_positions_are_the_scene_at_rest(tmp_path):
    from runout.gns.windows import TrainingWindows
    from test_gns_synthetic import write_dataset

    sims = TrainingWindows(write_dataset(tmp_path / "data", frames=20, n_train=1) / "train.npz", torch.device("cpu"))
    assert [sims._window(k)[4] for k in range(8)] == [6, 5, 4, 3, 2, 1, 0, 0]


def test_renormalising_keeps_the_predictions_and_takes_the_new_scales():
    """Fine-tuning at a lower noise (--init) narrows the scales; the model must predict the same
    next positions, so that training starts from the base's predictions."""
    frames, ptype = heap()
    sim = tiny_simulator()
    with torch.no_grad():  # a network whose velocity columns and output matter
        for p in sim.parameters():
            p.add_(0.3 * torch.randn_like(p))
    window, material = frames.transpose(0, 1), torch.full((40, 1), 0.5)
    with torch.no_grad():
        before = sim.next_positions(window, ptype, material, BOUNDS)
    narrow = Normalisation((0.004, -0.02), (0.05, 0.01), (1e-4, -2e-3), (1e-3, 5e-4), 1e-4)
    renormalise(sim, narrow)
    assert sim.stats == narrow
    torch.testing.assert_close(sim.acc_scale, torch.tensor([1e-3, 5e-4]).square().add(1e-8).sqrt())
    with torch.no_grad():
        after = sim.next_positions(window, ptype, material, BOUNDS)
    torch.testing.assert_close(after, before, rtol=0, atol=1e-5)  # m, of positions up to 22 m
    assert (after - window[:, -1]).abs().max() > 1e-3  # the check is not about a model that stands still


# ----------------------------------------------------------------------------- overburden input


def lattice(width_m: float, height_m: float, spacing: float = 4.0, x0: float = 0.0) -> torch.Tensor:
    """Points at the centres of a spacing-m lattice filling [x0, x0 + width] x [0, height] (m),
    as runout fills a scene (2 x 2 points per 8 m cell)."""
    xs = torch.arange(x0 + spacing / 2, x0 + width_m, spacing)
    ys = torch.arange(spacing / 2, height_m, spacing)
    X, Y = torch.meshgrid(xs, ys, indexing="ij")
    return torch.stack([X.flatten(), Y.flatten()], 1)


def test_overburden_is_the_depth_below_the_surface_at_rest():
    """A 2:1 slope at rest (lattice of 4 m, the model's columns of 8 m): each soil point's
    overburden equals the depth from the ground surface above it to the point, and kinematic
    points (ground) above do not count; two graphs are kept apart."""
    from runout.gns.features import overburden_depth

    block = lattice(80.0, 64.0)
    surface = 64.0 - 0.5 * torch.clamp(block[:, 0] - 16.0, min=0.0)  # flat crest, then a 1:2 face (m)
    points = block[block[:, 1] < surface]
    top_row = {}  # highest point of each 8 m column: the surface the lattice resolves
    for x, y in points.tolist():
        c = int(x // 8.0)
        top_row[c] = max(top_row.get(c, -1.0), y)
    want = torch.tensor([top_row[int(x // 8.0)] - y for x, y in points.tolist()])
    every = torch.ones(len(points), dtype=torch.bool)
    depth = overburden_depth(points, every, None, 8.0, 16.0)
    # on the face a column's two lattice columns end a row (4 m) apart: the depth there is their mean
    assert (depth - want).abs().max() <= 2.0 + 1e-4 and (depth - want)[points[:, 0] < 16.0].abs().max() < 1e-4
    flat = lattice(40.0, 40.0)  # top row at y = 38 m
    soil = torch.ones(len(flat), dtype=torch.bool)
    assert torch.allclose(overburden_depth(flat, soil, None, 8.0, 16.0), 38.0 - flat[:, 1])
    lid = torch.cat([flat, lattice(40.0, 4.0) + torch.tensor([0.0, 60.0])])  # a kinematic row above
    is_soil = torch.cat([soil, torch.zeros(len(lid) - len(flat), dtype=torch.bool)])
    assert torch.allclose(overburden_depth(lid, is_soil, None, 8.0, 16.0)[: len(flat)], 38.0 - flat[:, 1])
    two = torch.cat([flat, flat[flat[:, 1] < 20.0]])  # a second scene 20 m tall, in the same place
    graph = torch.cat([torch.zeros(len(flat)), torch.ones(len(two) - len(flat))]).long()
    depth2 = overburden_depth(two, torch.ones(len(two), dtype=torch.bool), graph, 8.0, 16.0)
    assert torch.allclose(depth2[: len(flat)], 38.0 - flat[:, 1]) and depth2[len(flat):].max() == 16.0


def test_a_model_with_the_overburden_input_sees_depth_and_round_trips(tmp_path):
    """With schema.overburden the node encoder takes one more column, the prediction at rest
    changes with the soil above a point, and a checkpoint keeps it; schemas without the field
    (older checkpoints) have none."""
    frames, ptype = heap()
    torch.manual_seed(0)
    schema = FeatureSchema(material_features=("tan_phi", "c_over_100kPa"), overburden=True)
    sim = GraphNetworkSimulator(schema, STATS, 4.6, TINY).eval()
    assert sim.schema.node_width == tiny_simulator(("tan_phi", "c_over_100kPa")).schema.node_width + 1
    material = torch.rand((40, 2))
    window = frames.transpose(0, 1)
    top = window[:, -1, 1] == window[:, -1, 1].max()
    shallower = window.clone()
    shallower[top, :, 0] += 20.0  # the heap's top row moved aside: the points below it lie 2 m less deep
    with torch.no_grad():
        nodes, moved = (sim.node_features(w, ptype, material, BOUNDS) for w in (window, shallower))
        column = 2 * 5 + 4  # the overburden column follows 10 velocities and 4 wall distances
        below = (ptype == 6) & ~top
        change = nodes[below, column] - moved[below, column]  # m / 100: one lattice row of 2 m spread over the column's
        assert change.min() >= 0.01 - 1e-6 and change.max() <= 0.02 + 1e-6  # width, which holds it whole (2 m) or half of it
        assert not torch.equal(sim(window, ptype, material, BOUNDS), sim(shallower, ptype, material, BOUNDS))
        save_checkpoint(tmp_path / "m.pt", sim, step=1)
        loaded = load_simulator(tmp_path / "m.pt")
        assert loaded.schema.overburden and torch.equal(sim.next_positions(window, ptype, material, BOUNDS),
                                                         loaded.next_positions(window, ptype, material, BOUNDS))
    assert FeatureSchema.from_dict({k: v for k, v in sim.schema.to_dict().items() if k != "overburden"}).overburden is False
    assert FeatureSchema.problem({**sim.schema.to_dict(), "overburden": 1}) == "overburden = 1 must be true or false"


# ----------------------------------------------------------------------------- rigid ground


def test_soil_does_not_pass_through_the_fixed_ground():
    """The MPM's fixed ground is rigid: a GNS step that would carry a soil point into it
    raises the point to its column's floor (the top ground point's centre less a quarter
    spacing), one that would carry it sideways into a step of the ground keeps its x as at a
    wall, and a point under an overhang of a fixed region is left alone."""
    ground = [(x, 2.0) for x in range(2, 40, 4)] + [(x, 6.0) for x in range(22, 40, 4)]  # a 4 m step up at x = 20 m
    overhang = [(34.0, 30.0)]
    soil = [(2.0, 6.0), (14.0, 6.0), (18.0, 3.5), (30.0, 10.0), (34.0, 20.0)]
    points = torch.tensor(ground + overhang + soil)
    ptype = torch.tensor([3] * (len(ground) + 1) + [6] * len(soil))
    constraints = Constraints.of(ptype, BOUNDS.new_tensor([[0.0, 40.0], [0.0, 40.0]]), points, None, 4.0)
    predicted = points.clone()
    predicted[-5:] = torch.tensor([[2.5, -5.0], [15.0, 0.5], [21.0, 3.0], [31.0, 8.0], [34.0, 19.0]])
    moved = constraints.constrain(predicted, points)
    assert torch.equal(moved[: len(ground) + 1], points[: len(ground) + 1])  # the fixed points stay
    assert moved[-5].tolist() == [2.5, 1.0]  # sank: raised to the floor, 2 - 1 m
    assert moved[-4].tolist() == [15.0, 1.0]
    assert moved[-3].tolist() == [18.0, 3.0]  # into the step's side: x kept, y as predicted (above its own floor)
    assert moved[-2].tolist() == [31.0, 8.0]  # above the step's floor (29 m): free
    assert moved[-1].tolist() == [34.0, 19.0]  # under the overhang (floor 29 m there): left alone
    walls_only = Constraints.of(ptype, constraints.bounds).constrain(predicted, points)[-5:]  # no ground given: the domain's bounds only
    assert torch.equal(walls_only, predicted[-5:].clamp(min=0.0))
    two = Constraints.of(torch.cat([ptype, ptype]), constraints.bounds, torch.cat([points, points + torch.tensor([0.0, 10.0])]),
                  torch.cat([torch.zeros(len(points)), torch.ones(len(points))]).long(), 4.0)
    lifted = two.constrain(torch.cat([predicted, predicted]), torch.cat([points, points + torch.tensor([0.0, 10.0])]))
    assert lifted[len(points) + len(ground) + 1].tolist() == [2.5, 11.0]  # each scene its own ground


def test_the_mpm_soil_stays_above_the_gns_floor():
    """The floor is the MPM's own behaviour: a column collapsing onto stepped fixed ground
    (8 m cells, 4 m points, 4.5 s) never puts a soil point below its column's floor, so the
    constraint takes away nothing the MPM would do."""
    from runout.gns.features import Ground
    from runout.mpm import simulate
    from runout.scene import scene_from_dict

    scene = scene_from_dict({
        "domain": {"width": 160.0, "height": 64.0, "cell_size": 8.0},
        "time": {"frames": 120},
        "materials": {"soil": {"friction_angle": 15.0, "cohesion": 2.0}, "ground": {"model": "elastic"}},
        "regions": [
            {"material": "ground", "polygon": [[0, 0], [160, 0], [160, 8], [0, 8]], "fixed": True},
            {"material": "ground", "polygon": [[56, 8], [160, 8], [160, 16], [56, 16]], "fixed": True},  # an 8 m step
            {"material": "soil", "polygon": [[0, 8], [40, 8], [40, 48], [0, 48]]},
        ],
    })
    t = simulate([scene], device="cpu", progress=False)[0]
    kinematic = torch.from_numpy(t.particle_type == 3)
    positions = torch.from_numpy(t.positions).double()
    ground = Ground.of(positions[0], kinematic, None, 4.0)
    soil = positions[:, ~kinematic]
    assert soil[-1, :, 0].max() > 64.0, "the soil must climb the step for the test to mean something"
    depth_below = max(float((ground.floor_at(soil[f], None) - soil[f, :, 1]).max()) for f in range(len(soil)))
    assert depth_below <= 0.0, f"MPM soil {depth_below:.2f} m below the GNS floor"
