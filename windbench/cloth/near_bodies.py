"""The parts of the cloth that may touch a body: gathered once, held while the cloth moves
less than a slack.

The body contacts' broad phase tests a vertex against the bodies' grown boxes
(:func:`~windbench.cloth.collision.near_a_body`) and an edge or triangle by the box of its
corners (:func:`~windbench.cloth.edge_contact.surface_contacts`), for every vertex, edge
and triangle in every substep and again after each strain-limit pass, although a flag
meets its pole along one hem only. Here the parts whose box comes within NEAR_SLACK of a
grown body box are gathered at positions q (:func:`gather_near`) and held while

    max_i |p_i - q_i| <= NEAR_SLACK                                   (:func:`hold_near`)

A part left out lay farther than NEAR_SLACK from every grown box along some axis; the box
of its corners has moved at most as far as its farthest corner since, so it still misses
them. The contacts test the held parts alone, with the same box test in the same order,
so the result is the same, bit for bit. The boxes do not change during a run: a still
body's is fixed, a moving body's is all space (it holds every part).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from windbench.arrays import copy_rows, largest_move

NEAR_SLACK = 0.05  # m a vertex may move before the held parts are gathered again


class NearBodies(NamedTuple):
    """The held parts (state: rewritten by :func:`hold_near`); ids ascending, the first
    ``counts[k]`` entries of each array valid."""

    anchor: np.ndarray  # (n, 3) positions of the last gather
    vertices: np.ndarray  # (n,) free vertices within the slack of a grown box
    edges: np.ndarray  # (E,) edges without a pinned corner ...
    triangles: np.ndarray  # (T,) ... and triangles, by the boxes of the thin bodies
    counts: np.ndarray  # (4,) held vertices, edges, triangles; 1 once gathered


def near_bodies(n_vertices: int, n_edges: int, n_triangles: int) -> NearBodies:
    """Empty held parts, to be gathered at their first use."""
    return NearBodies(
        np.zeros((n_vertices, 3)),
        np.empty(n_vertices, np.int64),
        np.empty(n_edges, np.int64),
        np.empty(n_triangles, np.int64),
        np.zeros(4, np.int64),
    )


@njit(cache=True)
def hold_near(boxes, thin_boxes, inv_mass, edges, triangles, p, near):
    """``near`` valid at ``p``: gathered again (:func:`gather_near`) unless no vertex has
    moved more than NEAR_SLACK since the last gather."""
    if near.counts[3] == 0 or largest_move(p, near.anchor) > NEAR_SLACK:
        gather_near(boxes, thin_boxes, inv_mass, edges, triangles, p, near)


@njit(cache=True)
def gather_near(boxes, thin_boxes, inv_mass, edges, triangles, p, near):
    """The free vertices whose point, and the edges and triangles without a pinned corner
    whose box of corners, come within NEAR_SLACK of a grown box (``boxes`` for the vertices,
    ``thin_boxes`` for the others) at ``p``, which becomes the anchor."""
    n = 0
    for i in range(p.shape[0]):
        if inv_mass[i] > 0.0 and box_within(boxes, p, i, i, i, NEAR_SLACK):
            near.vertices[n] = i
            n += 1
    near.counts[0] = n
    near.counts[1] = _gather_parts(thin_boxes, inv_mass, p, edges, near.edges)
    near.counts[2] = _gather_parts(thin_boxes, inv_mass, p, triangles, near.triangles)
    copy_rows(near.anchor, p, p.shape[0])
    near.counts[3] = 1


@njit(cache=True)
def _gather_parts(boxes, inv_mass, p, prims, out):
    """The rows of ``prims`` (2 or 3 corners) without a pinned corner whose box comes within
    NEAR_SLACK of a box of ``boxes``, written to ``out``; returns their count."""
    last = prims.shape[1] - 1
    n = 0
    for e in range(prims.shape[0]):
        a, b, c = prims[e, 0], prims[e, min(1, last)], prims[e, last]
        if inv_mass[a] > 0.0 and inv_mass[b] > 0.0 and inv_mass[c] > 0.0:
            if box_within(boxes, p, a, b, c, NEAR_SLACK):
                out[n] = e
                n += 1
    return n


@njit(cache=True, inline="always")
def box_within(boxes, p, a, b, c, gap):
    """Whether the box of the points a, b, c of ``p`` (a repeated id for an edge or a
    vertex) comes within ``gap`` of a box of ``boxes`` (lower and upper corners; indices,
    no array view: the broad phase, run for every part)."""
    for k in range(boxes.shape[0]):
        meets = True
        for ax in range(3):
            lo = min(p[a, ax], p[b, ax], p[c, ax])
            hi = max(p[a, ax], p[b, ax], p[c, ax])
            if hi + gap < boxes[k, ax] or lo - gap > boxes[k, 3 + ax]:
                meets = False
                break
        if meets:
            return True
    return False
