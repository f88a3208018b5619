import pytest
import torch

from runout.gns.graph import radius_graph

torch.set_num_threads(1)  # tiny graphs: extra threads only add OpenMP synchronisation cost


def brute_force(positions, radius, graph):
    d2 = (positions[:, None, :] - positions[None, :, :]).square().sum(-1)
    close = (d2 <= radius * radius) & (graph[:, None] == graph[None, :])
    receivers, senders = torch.nonzero(close, as_tuple=True)
    return senders, receivers


def edge_set(senders, receivers):
    pairs = torch.stack([senders, receivers], 1).cpu().tolist()
    assert len(pairs) == len(set(map(tuple, pairs))), "duplicate edges"
    return set(map(tuple, pairs))


def scattered_points(device):
    gen = torch.Generator().manual_seed(1)
    random = torch.rand((400, 2), generator=gen) * torch.tensor([60.0, 25.0]) - 5.0
    lattice = torch.stack(torch.meshgrid(torch.arange(10.0), torch.arange(6.0), indexing="ij"), -1).reshape(-1, 2) * 2.0
    positions = torch.cat([random, lattice, lattice[:5]])  # duplicates and exact lattice distances
    graph = torch.randint(0, 3, (len(positions),), generator=gen)
    return positions.to(device), graph.to(device)


DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("radius", [2.0, 4.6, 11.0])
def test_cell_list_search_equals_brute_force(device, radius):
    positions, graph = scattered_points(device)
    found = edge_set(*radius_graph(positions, radius, graph))
    assert found == edge_set(*brute_force(positions, radius, graph))


def test_no_cap_on_neighbours_in_a_dense_cluster():
    positions = torch.rand((300, 2)) * 0.5  # every point within R of every other
    senders, receivers = radius_graph(positions, 1.0)
    assert len(senders) == 300 * 300


def test_points_of_different_graphs_never_connect():
    positions = torch.zeros((4, 2))
    senders, receivers = radius_graph(positions, 1.0, torch.tensor([0, 0, 1, 1]))
    assert edge_set(senders, receivers) == {(0, 0), (0, 1), (1, 0), (1, 1), (2, 2), (2, 3), (3, 2), (3, 3)}
