"""What the two AGV layouts share (Figure 4.4's ``envs.agv``, Figure 6.2's ``envs.four_agv``).

A layout is a one-way graph over numbered locations (``succ [n_locations, n_moves]``: the next
location of each move, the location itself where a move does not branch); an AGV's flat state is
a mixed-radix number of its location, status, the stations' buffers and the warehouse bits.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch


def station_of(n_locations: int, locations: Sequence[int]) -> torch.Tensor:
    """``[n_locations]`` long: ``i`` at ``locations[i]``, -1 elsewhere."""
    table = torch.full((n_locations,), -1, dtype=torch.long)
    table[list(locations)] = torch.arange(len(locations))
    return table


def shortest_paths(succ: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Shortest routes over the layout ``succ [n, n_moves]``.

    Returns:
        ``(distance, first_move)``, both ``[n, n]`` long indexed ``[from, to]``: the number of
        moves on a shortest path and its first move (the first in move order among equally
        short ones; 0 where from == to).
    """
    n = succ.shape[0]
    into: list[list[int]] = [[] for _ in range(n)]  # predecessors
    for node, row in enumerate(succ.tolist()):
        for s in set(row) - {node}:
            into[s].append(node)
    far = n + 1
    dist = torch.full((n, n), far, dtype=torch.long)
    for target in range(n):  # backward breadth-first search from each target
        dist[target, target] = 0
        frontier = [target]
        while frontier:
            nxt = []
            for s in frontier:
                for node in into[s]:
                    if dist[node, target] == far:
                        dist[node, target] = dist[s, target] + 1
                        nxt.append(node)
            frontier = nxt
    if bool((dist >= far).any()):
        raise RuntimeError("the AGV layout is not strongly connected")
    # the first move (in move order) whose successor is one move closer
    closer = dist[succ] == (dist[:, None, :] - 1)  # [from, move, to]
    closer &= succ[:, :, None] != torch.arange(n)[:, None, None]
    return dist, closer.long().argmax(1)


def radices(n_locations: int, n_stations: int, capacity: int) -> tuple[int, ...]:
    """Radices of the flat state: location, status, the ``2 n`` buffers, ``n`` warehouse bits."""
    n_status = 1 + 2 * n_stations
    return (n_locations, n_status, *([capacity + 1] * 2 * n_stations), *([2] * n_stations))


def encode(radix: Sequence[int], location, status, drop_off, pick_up, warehouse) -> torch.Tensor:
    """Flat state index (mixed radix ``radix``, most significant first).

    ``location``, ``status`` ``[...]``; ``drop_off``, ``pick_up``, ``warehouse`` ``[..., n]``.
    """
    digits = [location, status, *drop_off.unbind(-1), *pick_up.unbind(-1), *warehouse.unbind(-1)]
    index = torch.zeros_like(torch.as_tensor(location), dtype=torch.long)
    for digit, base in zip(digits, radix, strict=True):
        index = index * base + torch.as_tensor(digit).long()
    return index


def decode(radix: Sequence[int], index: torch.Tensor) -> dict[str, torch.Tensor]:
    """Observation fields of flat state indices (any shape): ``encode``'s digits by name."""
    rest, digits = index.long(), []
    for base in reversed(radix):
        digits.append(rest % base)
        rest = rest // base
    digits.reverse()
    fields = {"observation": index.long(), "location": digits[0], "status": digits[1]}
    n = (len(radix) - 2) // 3
    for i in range(n):
        fields[f"drop_off_{i + 1}"] = digits[2 + i]
        fields[f"pick_up_{i + 1}"] = digits[2 + n + i]
        fields[f"warehouse_{i + 1}"] = digits[2 + 2 * n + i]
    return fields
