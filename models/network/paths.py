"""The one switch between the network model's fast and plain forms of a step.

Every shortcut of the frame (a small scene's steps in Python floats, a frame's messages reused,
record groups of the display error, ...) has a plain form beside it computing the same values;
:class:`Paths` says which runs. The model takes one (``NetworkModel(cfg, paths)``); the default
is every shortcut where it pays, :meth:`Paths.plain` every step in its plain array form. Both give
the same outputs bit for bit (tests/network checks each pair); only the time differs.
"""
from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Paths:
    """Which form of each step runs (thresholds in view pairs, records or objects; -1: never).

    Attributes
    ----------
    scalar_view : int, at most this many view pairs: display error, avatar history, cells and
        frame flips in Python floats; at most this many objects: a frame's positions as a list
    memo_pairs : int, at most this many view pairs: a frame's messages reused from the last one
    few_records : int, at most this many records in a small lossless batch: filed as lists
    rest_display : bool, a resting scene whose copies hold records of that state skips the
        display error (all zeros)
    groups_min_pairs : int, more view pairs than this: the display error keeps record groups
        (one evaluation per distinct record, :class:`display.DisplayGroups`)
    measure_chunk : int, copies per chunk of the per-copy display error (fits a core's cache)
    reuse_views : bool, the last frame's view pairs reused while no object changes cell and
        the same groups are online
    scalar_grid : int, at most this many (viewer, object) candidates or view pairs: the grid's
        view pairs and view entries in Python (:class:`consistency.SceneGrid`)
    scalar_owners : int, at most this many (avatar, entity) pairs: ownership in Python floats
    brute_owners : int, below this many (avatar, entity) pairs ownership takes every pair
        instead of building a k-d tree
    scalar_messages : int, at most this many view pairs: hybrid_p2p messages built in Python
    float_batch : int, a merged batch of at most this many messages timed in Python floats
    merge_draws : bool, the jitter of several exponential lossless link classes drawn in one call
    scalar_avatars, scalar_entities : int, up to this many avatars (entities): kinematics in
        Python floats
    rest_skip : bool, avatars at a sub-step fixed point not sub-stepped (their arrays reused)
    scalar_contacts : int, up to this many avatar-entity pairs: the contact pre-check in Python
    """

    scalar_view: int = 64
    memo_pairs: int = 4096
    few_records: int = 8
    rest_display: bool = True
    groups_min_pairs: int = 4096
    measure_chunk: int = 16384
    reuse_views: bool = True
    scalar_grid: int = 256
    scalar_owners: int = 256
    brute_owners: int = 4096
    scalar_messages: int = 256
    float_batch: int = 64
    merge_draws: bool = True
    scalar_avatars: int = 8
    scalar_entities: int = 32
    rest_skip: bool = True
    scalar_contacts: int = 64

    @classmethod
    def plain(cls, **keep) -> "Paths":
        """Every step in its plain form (arrays, nothing reused), but for the fields in ``keep``
        (``brute_owners`` is kept: brute force and a k-d tree are both plain)."""
        return replace(cls(scalar_view=-1, memo_pairs=-1, few_records=-1, rest_display=False,
                           groups_min_pairs=10 ** 12, reuse_views=False, scalar_grid=-1, scalar_owners=-1,
                           scalar_messages=-1, float_batch=-1, merge_draws=False, scalar_avatars=-1,
                           scalar_entities=-1, rest_skip=False, scalar_contacts=-1), **keep)
