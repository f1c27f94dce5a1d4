"""Counter-based random numbers for a population of learners.

Every env row ``b`` belongs to learner ``p = b // E`` and has local index ``e = b % E``. A draw
hashes ``(seed_p, e, stream, counter)``, so learner ``p`` sees the same numbers whether it runs
alone or inside a population of any size: the property the population tests rely on. The hash
is a 32-bit integer mixer evaluated in int64 without overflow, so it gives the same bits on
every device.
"""

from __future__ import annotations

import copy
import numbers
from collections.abc import Sequence

import torch

from hrl_torch.common.devices import from_host

_MASK32 = 0xFFFFFFFF
SEED_LIMIT = 2**32  # seeds are hashed as 32-bit keys: larger ones would collide, so refused


def check_seeds(seeds: Sequence[int]) -> list[int]:
    """``seeds`` as a list of distinct integers in ``[0, SEED_LIMIT)``; ``ValueError`` if not."""
    seeds = list(seeds)
    if not seeds:
        raise ValueError("seeds must name at least one seed, got none")
    bad = [s for s in seeds if isinstance(s, bool) or not isinstance(s, numbers.Integral)]
    if bad:
        raise ValueError(f"seeds must be integers, got {bad[0]!r}")
    seeds = [int(s) for s in seeds]
    outside = [s for s in seeds if not 0 <= s < SEED_LIMIT]
    if outside:
        raise ValueError(
            f"seed {outside[0]} is outside [0, 2**32): the random streams hash 32-bit seeds, "
            "so larger seeds would repeat smaller ones"
        )
    if len(set(seeds)) < len(seeds):
        raise ValueError(f"seeds must be distinct (each names one learner), got {seeds}")
    return seeds


_MULT = 0x045D9F3B  # < 2**27, so (x < 2**32) * _MULT stays below 2**63


def mix32(x: torch.Tensor) -> torch.Tensor:
    """Hash int64 values in ``[0, 2**32)`` to ``[0, 2**32)`` (shape preserved).

    (In place on a fresh tensor after the first op: a block of draws is a few MB, and new
    buffers per op cost a third more.)
    """
    x = x ^ (x >> 16)
    x.mul_(_MULT).bitwise_and_(_MASK32)
    x.bitwise_xor_(x >> 16)
    x.mul_(_MULT).bitwise_and_(_MASK32)
    return x.bitwise_xor_(x >> 16)


def _bits32(x: torch.Tensor) -> torch.Tensor:
    """int64 values in ``[0, 2**32)`` as int32 tensors holding the same 32 bits."""
    return (x - ((x >> 31) << 32)).to(torch.int32)


def _signed32(value: int) -> int:
    """A 32-bit value as the int32 holding its bits (``_bits32`` of one number)."""
    return value - (1 << 32) if value >= 1 << 31 else value


def _lsr16(x: torch.Tensor) -> torch.Tensor:
    """``x >> 16`` of int32 bit patterns read as unsigned (a logical shift)."""
    return (x >> 16).bitwise_and_(0xFFFF)


def mix32_bits(x: torch.Tensor) -> torch.Tensor:
    """``mix32`` on int32 bit patterns (``_bits32``): the same 32 bits, half the memory.

    The multiplications wrap modulo ``2**32``, which is what ``mix32``'s mask keeps. (A block of
    draws: 1.09 ms in int64, 0.45 ms here, for ``[14, 1000, 18]`` on one CPU thread.)
    """
    x = x ^ _lsr16(x)
    x.mul_(_MULT)
    x.bitwise_xor_(_lsr16(x))
    x.mul_(_MULT)
    return x.bitwise_xor_(_lsr16(x))


def _mix32_int(x: int) -> int:
    x &= _MASK32
    x ^= x >> 16
    x = (x * _MULT) & _MASK32
    x ^= x >> 16
    x = (x * _MULT) & _MASK32
    return x ^ (x >> 16)


def _draw_key(counter: int) -> int:
    """The hash key of draw number ``counter`` (its columns' keys are ``mix(j + key)``)."""
    return _mix32_int(counter * 0x9E3779B1 + 0x7F4A7C15)


def _to_uniform(bits: torch.Tensor) -> torch.Tensor:
    """32-bit integers to float32 uniforms in ``[0, 1)`` (their top 24 bits).

    ``bits``: int64 values in ``[0, 2**32)``, or int32 bit patterns (``mix32_bits``).
    """
    top = bits >> 8
    if bits.dtype == torch.int32:
        top = top.bitwise_and_(0xFFFFFF)
    return top.to(torch.float32) * (1.0 / 16777216.0)


class BatchRNG:
    """Reproducible uniform numbers for ``B = P * E`` rows, one independent stream per row.

    Draw number ``c`` of a row is a function of the row's key and ``c`` alone.

    Args:
        seeds: one seed per learner (length ``P``).
        envs_per_learner: ``E``, rows per learner.
        stream: a name that separates independent uses (env dynamics, exploration, ...).
        device: where draws are made.
    """

    AHEAD = 64  # draws of one kind computed at once (see ``_draw``)
    AHEAD_ELEMENTS = 1 << 18

    def __init__(
        self,
        seeds: Sequence[int],
        envs_per_learner: int,
        stream: str,
        device: torch.device | str = "cpu",
    ) -> None:
        if envs_per_learner < 1:
            raise ValueError(f"envs_per_learner must be >= 1, got {envs_per_learner}")
        if any(not 0 <= int(s) < SEED_LIMIT for s in seeds):
            raise ValueError(f"seeds must lie in [0, 2**32), got {list(seeds)}")
        self.device = torch.device(device)
        self.n_learners = len(seeds)
        self.envs_per_learner = envs_per_learner
        stream_key = _mix32_int(sum(ord(c) * 131**k for k, c in enumerate(stream)))
        seed_keys = torch.tensor(
            [_mix32_int(_mix32_int(int(s)) ^ stream_key) for s in seeds],
            dtype=torch.int64,
            device=self.device,
        )
        local = torch.arange(envs_per_learner, dtype=torch.int64, device=self.device)
        self._row_key = mix32(
            seed_keys.repeat_interleave(envs_per_learner) ^ local.repeat(len(seeds))
        )
        self.counter = 0
        self._ahead: dict = {}  # kind -> (first draw, its draws onward, the columns)
        self.device_counter: torch.Tensor | None = None  # (``count_on_device``)
        self._counted = 0  # ``counter`` when ``device_counter`` last matched it
        self._col_keys: dict = {}  # tuple of columns -> their numbers on the device
        self._known: dict = {}  # id(columns) -> (columns, their values as a list)

    def know_columns(self, columns: torch.Tensor, values: list[int]) -> None:
        """``columns``'s values (as built, on the host): drawing them reads no device."""
        self._known[id(columns)] = (columns, values)

    def _column_list(self, columns: torch.Tensor) -> list[int]:
        known = self._known.get(id(columns))
        return known[1] if known is not None else columns.reshape(-1).tolist()

    @property
    def batch_size(self) -> int:
        """Number of rows ``B``."""
        return self._row_key.shape[0]

    def _bits(self, extra: int, first: int, k: int = 1, cols=None, rows=None) -> torch.Tensor:
        """32-bit integers ``[k, B]`` or ``[k, B, C]``: draws ``first .. first + k - 1``.

        ``C`` columns: ``cols`` (a list of column numbers of a draw of width ``extra``; a
        column's numbers do not depend on the width), else all ``extra``. ``rows``: the
        indices of some rows only (default: every row). As int32 bit patterns
        (``mix32_bits``: the numbers of ``mix32``, half the memory).
        """
        row_key = self._row_key32()
        if rows is not None:
            row_key = row_key.index_select(0, rows)
        bases = [_draw_key(c) for c in range(first, first + k)]
        if extra == 0:
            keys = from_host([_signed32(b) for b in bases], torch.int32, self.device)
            return mix32_bits(row_key[None, :] ^ keys[:, None])
        # the column keys are a handful of numbers: hashed in Python, one tensor
        cols = range(extra) if cols is None else cols
        keys = [[_signed32(_mix32_int(j + base)) for j in cols] for base in bases]
        keys = from_host(keys, torch.int32, self.device)
        return mix32_bits(row_key[None, :, None] ^ keys[:, None, :])

    def _row_key32(self) -> torch.Tensor:
        """The row keys as int32 bit patterns (``_bits32``), kept while the keys are."""
        cached = self.__dict__.get("_key32")
        if cached is None or cached[0] is not self._row_key:
            cached = self._key32 = (self._row_key, _bits32(self._row_key))
        return cached[1]

    def uniform(
        self, extra: int = 0, counter: int | None = None, columns: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Float32 uniforms in ``[0, 1)``, shape ``[B]`` (or ``[B, extra]`` when ``extra > 0``).

        ``counter`` reads a given draw number instead of the next one (see ``reserve``);
        ``columns`` (a fixed index tensor of any shape) gives ``uniform(extra)[:, columns]``
        ``[B, *columns.shape]``, computing only those columns.
        """
        if columns is None:
            return self._draw(extra, extra, counter)
        return self._draw((extra, id(columns)), extra, counter, columns)

    def _draw(self, key, extra: int, counter: int | None, columns=None, transform=None):
        """Draw ``counter`` (the next one if ``None``) of width ``extra`` (or its ``columns``).

        The next draws of one kind (``key``) are computed ahead in blocks (up to ``AHEAD``,
        at most about ``AHEAD_ELEMENTS`` numbers at once): a draw is a function of its number
        alone, so a block holds exactly what the draws one by one would, made by one set of
        ops. ``transform`` maps a block of uniforms to what is kept (e.g. integers).
        """
        if counter is None:
            counter = self.counter
            self.counter += 1
        if self.device_counter is not None:  # (replayable: no block, the number on the device)
            u = self._at_device(extra, counter, columns)
            return u if transform is None else transform(u)
        block = self._ahead.get(key)
        if block is None or not block[0] <= counter < block[0] + block[1].shape[0]:
            u = self._block(extra, counter, columns)
            block = (counter, u if transform is None else transform(u), columns)
            self._ahead[key] = block  # (the key's columns are held with the block)
        return block[1][counter - block[0]]

    def _block(self, extra: int, first: int, columns=None) -> torch.Tensor:
        """Uniforms of the draws from ``first`` on: ``[k, B, ...]`` (``uniform``'s shapes)."""
        listed = None if columns is None else self._column_list(columns)
        needed = None if columns is None else sorted(set(listed))
        per_draw = self.batch_size * max(extra if needed is None else len(needed), 1)
        k = max(1, min(self.AHEAD, self.AHEAD_ELEMENTS // max(per_draw, 1)))
        u = _to_uniform(self._bits(extra, first, k, needed))
        if needed is None:
            return u
        where = from_host([needed.index(c) for c in listed], torch.int64, u.device)
        # (a gather: ``index_select`` along the last dimension copies element by element)
        return u.gather(-1, where.expand(*u.shape[:2], -1)).view(*u.shape[:2], *columns.shape)

    def uniform_rows(
        self, extra: int, counter: int, rows: torch.Tensor, columns: torch.Tensor
    ) -> torch.Tensor:
        """Draw ``counter``'s columns ``columns`` (any shape) for the rows ``rows [R]`` only.

        ``[R, *columns.shape]``, what ``uniform(extra, counter, columns)[rows]`` gives,
        computing only those numbers (for large batches of which few rows need a draw).
        """
        if self.device_counter is not None:
            return self._at_device(extra, counter, columns, self._row_key.index_select(0, rows))
        bits = self._bits(extra, counter, 1, self._column_list(columns), rows)
        return _to_uniform(bits).view(rows.shape[0], *columns.shape)

    def count_on_device(self) -> None:
        """Draw numbers from a device counter from now on (a CUDA graph replays its draws).

        A draw number is then ``device_counter + (counter - counted)``: the offset within a
        step is the same every step, so a replayed step reads fresh draws once ``sync_counter``
        (in the replayed step) has moved the device counter on. Same numbers as the blocks.
        """
        if self.device_counter is None:
            self.device_counter = torch.tensor(self.counter, dtype=torch.int64, device=self.device)
            self._counted = self.counter

    def sync_counter(self) -> None:
        """Move the device counter on by the draws taken since the last call (in place)."""
        if self.device_counter is not None:
            self.device_counter.add_(self.counter - self._counted)
            self._counted = self.counter

    def _at_device(self, extra: int, counter: int, columns=None, row_key=None) -> torch.Tensor:
        """Draw ``counter`` (``uniform``'s shapes) hashed from ``device_counter`` on the device."""
        row_key = self._row_key if row_key is None else row_key
        number = self.device_counter + (counter - self._counted)
        base = mix32((number * 0x9E3779B1 + 0x7F4A7C15) & _MASK32)  # ``_draw_key`` on the device
        if extra == 0:
            return _to_uniform(mix32(row_key ^ base))
        listed = tuple(range(extra) if columns is None else self._column_list(columns))
        cols = self._col_keys.get(listed)
        if cols is None:  # (made once, before a capture: a graph copies nothing from the host)
            cols = self._col_keys[listed] = torch.tensor(listed, device=self.device)
        keys = mix32((cols + base) & _MASK32)
        u = _to_uniform(mix32(row_key[:, None] ^ keys[None, :]))
        return u if columns is None else u.view(row_key.shape[0], *columns.shape)

    def reserve(self, n: int) -> int:
        """Reserve ``n`` draw numbers; returns the first (read them with ``counter=``)."""
        first = self.counter
        self.counter += n
        return first

    def integers(self, high: torch.Tensor | int, extra: int = 0) -> torch.Tensor:
        """Integers uniform in ``[0, high)``; ``high`` may be a per-row tensor of shape ``[B]``."""
        if isinstance(high, torch.Tensor):
            u = self.uniform(extra)
            high = high.long()
            if extra:
                high = high[:, None]
            return torch.minimum((u * high).long(), high - 1)
        return self._draw(
            ("int", extra, high),
            extra,
            None,
            transform=lambda u: (u * high).long().clamp_max(high - 1),
        )

    def normal(self, extra: int = 0) -> torch.Tensor:
        """Standard normal draws (Box-Muller on two uniform draws)."""
        u1 = self.uniform(extra).clamp_min(1e-7)
        u2 = self.uniform(extra)
        return torch.sqrt(-2.0 * torch.log(u1)) * torch.cos(2.0 * torch.pi * u2)

    def subset(self, rows: torch.Tensor) -> BatchRNG:
        """The streams of ``rows`` only, at the same counter: each row draws what it drew here."""
        sub = copy.copy(self)
        sub._row_key = self._row_key[rows]
        sub._ahead = {}
        if self.device_counter is not None:  # (its own counter: the two move apart)
            sub.device_counter = self.device_counter.clone()
        return sub

    def to(self, device: torch.device | str) -> BatchRNG:
        """The same streams, drawn on ``device`` (the draws do not depend on the device)."""
        self.device = torch.device(device)
        self._row_key = self._row_key.to(self.device)
        self._ahead = {}
        if self.device_counter is not None:
            self.device_counter = self.device_counter.to(self.device)
            self._col_keys = {k: v.to(self.device) for k, v in self._col_keys.items()}
        return self

    def state_dict(self) -> dict[str, int]:
        """The counter: all a checkpoint needs to continue the stream."""
        return {"counter": self.counter}

    def load_state_dict(self, state: dict[str, int]) -> None:
        """Continue from a saved counter."""
        self.counter = int(state["counter"])
        if self.device_counter is not None:
            self.device_counter.fill_(self.counter)
            self._counted = self.counter


def choosing_levels(graph, width: int) -> torch.Tensor:
    """Columns ``[levels - 1, width]`` of a draw of ``width`` numbers per stack level.

    The deepest level holds a primitive and never chooses: a policy whose draw has a block
    per level reads only these (``BatchRNG.uniform(columns=...)`` computes only them, the
    same numbers as the whole draw's).
    """
    levels = max(graph.max_levels - 1, 1)
    return torch.arange(levels)[:, None] * width + torch.arange(width)


class LevelDraws:
    """A policy's random numbers: one draw per step, ``per_level`` uniforms per stack level.

    A choice at stack level ``l`` reads block ``l`` of the step's draw, so a row's numbers
    never depend on what other rows do. Only the levels that can choose are read
    (``choosing_levels``), and each read computes only what it returns.

    Args:
        rng: the rows' streams.
        graph: the task graph (its ``max_levels``).
        per_level: uniforms per level.
    """

    def __init__(self, rng: BatchRNG, graph, per_level: int) -> None:
        self.rng = rng
        self.width = graph.max_levels * per_level  # of the whole draw
        levels = choosing_levels(graph, per_level)  # [levels - 1, per_level] (on the CPU)
        self.levels = levels.to(rng.device)
        self._by_level = list(self.levels)  # (fixed views: the rng knows their values)
        rng.know_columns(self.levels, levels.reshape(-1).tolist())
        for block, values in zip(self._by_level, levels.tolist(), strict=True):
            rng.know_columns(block, values)
        self.counter: int | None = None

    def new_step(self) -> None:
        """Take this step's draw."""
        self.counter = self.rng.reserve(1)

    def columns(self, columns: torch.Tensor) -> torch.Tensor:
        """This step's ``columns`` (a fixed tensor of any shape) of every row."""
        return self.rng.uniform(self.width, counter=self.counter, columns=columns)

    def level(self, level: int) -> torch.Tensor:
        """Every row's block of ``level`` ``[B, per_level]``."""
        return self.columns(self.levels)[:, level]

    def level_rows(self, level: int, rows: torch.Tensor) -> torch.Tensor:
        """The block of ``level`` of the batch rows ``rows [R]`` only ``[R, per_level]``."""
        return self.rng.uniform_rows(self.width, self.counter, rows, self._by_level[level])
