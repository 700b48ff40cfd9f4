"""The rounds of the DA-HGNN network (:mod:`areasearch.models.network`): one :class:`Round` of attention over
every graph (eqs. 6-13 of the paper; its docstring lists the graphs), the :class:`Context` that every
round of a forward pass reads (masks, neighbour rows, edge features; :func:`build_context`) and the
health probes that :func:`areasearch.models.dahgnn.diagnose` records.

Axes: B batch, R robots, C candidates, N history nodes, P packed (real) candidates, K neighbours,
D width, E edge width.
"""

from __future__ import annotations

import math
from typing import NamedTuple, cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .blocks import Encoders, NodeUpdate, Projections, flat_rows
from .cross_attention import cross_attention
from .graph import GraphBatch
from .kernels import pair_rows
from .network_config import NetworkConfig
from .self_attention import sparse_attention

CAP = 10.0
"""MLP-attention logits are soft-capped to +-CAP (tanh), so that their exponentials need no
max-subtraction: one exponential per pair serves every normalisation of the pair's score."""


class State(NamedTuple):
    robots: Tensor  # (B, R, D)
    goals: Tensor  # (P, D): the real candidates only (see Context.real)
    past: Tensor | None  # (B, 2N, Dh): historical robots, then historical goals


class Context(NamedTuple):
    """What every round reads, computed once per forward: masks, neighbour rows, edge features (each
    round's attention kernels project them with its own weights, on the real pairs only)."""

    b: int
    r: int
    c: int
    n: int
    real: Tensor | None  # (P,) rows of the real candidates in the flattened (B * C) ones; None: all are
    cand_groups: list[int]  # first (packed) candidate row of each decision
    robot_rows: Tensor  # (B * R, 1, R) neighbour rows of G_r
    robot_mask: Tensor  # (B, R) bool: real robots
    kind: Tensor  # (B, C) int64: a real candidate's kind (0 frontier, 1 target), -1 for padding
    cand_rows: Tensor  # (P, G, K) neighbour rows (packed) of G_g [then of G_e / G_c]
    pair_rows: Tensor  # (B, R, C) row of each robot-candidate pair in the pair table, -1: not a pair
    pair_edges: Tensor  # (N, E) the pair table's edge features (distance encoder)
    similarity_rows: Tensor  # (B, R, C) pair_rows of the pairs the action mask allows, -1 elsewhere
    past_rows: Tensor | None  # (B * 2N, 1, K) neighbour rows of G_r' and G_g'
    past_cand_rows: Tensor | None  # (B * N, G, K) neighbour rows (packed candidates) of G_r'e [then G_r'c]
    past_kind: Tensor | None  # (B, 2N) int64: 0 historical robot, 1 historical goal
    past_pair_rows: Tensor | None  # (B, R, 2N) row of each robot-history pair in its table, -1: none
    past_edges: Tensor | None  # (N', E) that table's edge features (Euclidean distances)


def build_context(cfg: NetworkConfig, enc: Encoders, batch: GraphBatch) -> Context:
    """The context of a forward pass of a network of ``cfg`` (its ``enc`` encodes the edges) over ``batch``."""
    rm, cm = batch.robot_mask, batch.cand_mask
    b, nr = rm.shape
    nc = cm.shape[1]
    counts = cm.sum(1)
    real = None if bool((counts == nc).all()) else cm.flatten().nonzero().squeeze(1)
    packed = None
    if real is not None:  # flat candidate row -> packed row
        packed = torch.full((b * nc,), -1, dtype=torch.long, device=cm.device)
        packed[real] = torch.arange(real.numel(), device=cm.device)

    def to_packed(idx: Tensor) -> Tensor:
        return idx if packed is None else torch.where(idx >= 0, packed[idx.clamp(min=0)], -1)

    rows = flat_rows(batch.cand_nbr, nc)[:, :, None]  # (B, C, 1, K)
    if cfg.type_aware:
        rows = torch.cat([rows, flat_rows(batch.cand_kin, nc)[:, :, None]], dim=2)
    rows = rows.flatten(0, 1)
    robot_rows = flat_rows(torch.where(rm, torch.arange(nr, device=rm.device), -1)[:, None].expand(b, nr, nr), nr)
    past_rows = past_cand_rows = to_past = past_kind = past_pair = past_edges = None
    if cfg.history:
        p, q = batch.past_robot_mask, batch.past_goal_mask
        n = p.shape[1]
        goal_nbr = torch.where(batch.past_goal_nbr >= 0, batch.past_goal_nbr + n, -1)
        both = flat_rows(torch.cat([batch.past_robot_nbr, goal_nbr], dim=1), 2 * n)  # (B, 2N, K)
        past_rows = both.flatten(0, 1)[:, None]  # (B * 2N, 1, K)
        cand = to_packed(flat_rows(batch.past_cand, nc))  # (B, N, 2, K)
        if not cfg.type_aware:
            cand = cand.flatten(2, 3)[:, :, None]  # G_r'g: the nearest frontiers and the nearest targets
        past_cand_rows = cand.flatten(0, 1)  # (B * N, typed, K)
        to_past = rm[:, :, None] & torch.cat([p, q], dim=1)[:, None]  # (B, R, 2N)
        past_kind = (torch.arange(2 * n, device=p.device) >= n).long().expand(b, -1)
        xy = torch.cat([batch.past_robot_xy, batch.past_goal_xy], dim=1)  # (B, 2N, 2)
        past_pair, index = pair_rows(to_past)
        past_edges = enc.euclidean(batch.robot_xy, xy, cfg.graph.distance_scale_m, index)
    pair = rm[:, :, None] & cm[:, None, :]
    rows_of_pairs, index = pair_rows(pair)
    return Context(
        b=b,
        r=nr,
        c=nc,
        n=batch.past_robot_mask.shape[1],
        real=real,
        cand_groups=[0, *torch.cumsum(counts, 0)[:-1].tolist()],
        robot_rows=robot_rows.flatten(0, 1)[:, None],
        robot_mask=rm,
        kind=torch.where(cm, batch.cand_kind, -1),
        cand_rows=to_packed(rows if real is None else rows.index_select(0, real)),
        pair_rows=rows_of_pairs,
        pair_edges=enc.geodesic(batch, index),
        similarity_rows=torch.where(batch.action_mask, rows_of_pairs, -1),
        past_rows=past_rows,
        past_cand_rows=past_cand_rows,
        past_kind=past_kind,
        past_pair_rows=past_pair,
        past_edges=past_edges,
    )


def padded(x: Tensor, ctx: Context) -> Tensor:
    """Packed candidate rows (P, w) -> (B, C, w), zeros on the padded candidates."""
    if ctx.real is not None:
        x = x.new_zeros(ctx.b * ctx.c, x.shape[1]).index_copy(0, ctx.real, x)
    return x.view(ctx.b, ctx.c, -1)


def packed(x: Tensor, ctx: Context) -> Tensor:
    """(B, C, w) -> the packed candidate rows (P, w)."""
    x = x.flatten(0, 1)
    return x if ctx.real is None else x.index_select(0, ctx.real)


# ---------------------------------------------------------------------------------------------- health probes
# What diagnose (areasearch.models.dahgnn) records of a forward pass (plain torch, on the side of the
# kernels): the scale of the features each round reads, how peaked the candidates' self-attention is,
# how many robot-goal MLP-attention logits sit on the flat part of their tanh cap. Unnormalised rounds
# let all three run away during training (docs/dahgnn.md#normalisation); these are the numbers that show it.


def _rms(x: Tensor) -> float:
    return float(x.pow(2).mean().sqrt()) if x.numel() else 0.0


def probe_features(probe: dict[str, float], name: str, r: Tensor, g: Tensor, ctx: Context) -> None:
    probe[f"{name}_robot_rms"] = _rms(r[ctx.robot_mask])
    probe[f"{name}_goal_rms"] = _rms(g)


def _probe_scores(probe: dict[str, float], name: str, q: Tensor, k: Tensor, idx: Tensor) -> None:
    """Spread (largest less smallest logit) and largest weight of the candidates' dot-product
    self-attention, averaged over the (row, head) pairs with at least two neighbours."""
    h = q.shape[1]
    rows = idx.repeat_interleave(h // idx.shape[1], dim=1)  # (P, H, K)
    ok = rows >= 0
    heads = torch.arange(h)[None, :, None].expand_as(rows)
    logits = (k[rows.clamp(min=0), heads % k.shape[1]] * q[:, :, None]).sum(-1)  # (P, H, K)
    many = ok.sum(-1) >= 2
    if not bool(many.any()):
        probe[f"{name}_score_spread"] = probe[f"{name}_max_attention"] = 0.0
        return
    spread = logits.masked_fill(~ok, -math.inf).amax(-1) - logits.masked_fill(~ok, math.inf).amin(-1)
    weights = torch.softmax(logits.masked_fill(~ok, -math.inf), dim=-1).amax(-1)
    probe[f"{name}_score_spread"] = float(spread[many].mean())
    probe[f"{name}_max_attention"] = float(weights[many].mean())


def _probe_saturation(
    probe: dict[str, float], name: str, edges: Tensor, rows: Tensor, p_part: Tensor, q_part: Tensor, logits: nn.Linear
) -> None:
    """Share of the robot-candidate MLP-attention logits (eq. 9) whose tanh cap is saturated (|tanh| > 0.99)."""
    ok = rows >= 0
    if not bool(ok.any()):
        probe[f"{name}_cross_saturated"] = 0.0
        return
    b, p, q = ok.nonzero().unbind(1)
    z = torch.relu(edges[rows[ok]] + p_part[b, p] + q_part[b, q])
    t = torch.tanh(F.linear(z, logits.weight, logits.bias) / CAP)
    probe[f"{name}_cross_saturated"] = float((t.abs() > 0.99).float().mean())


class Round(nn.Module):
    """One round of attention over every graph (all messages read the features of the previous round).

    * eqs. 6-8: dot-product self-graphs G_r (robots, dense), G_g (each candidate over its K nearest
      candidates), G_r', G_g' (each history node over its K nearest of its own set);
    * eqs. 9-10: the robot-goal cross-graph G_rg both ways, MLP attention over [robot || candidate ||
      distance]; with type awareness G_re and G_rc (eq. 12: robots <- frontiers, robots <- targets);
    * eq. 11: the type-aware self-graphs G_e and G_c: each candidate over its K nearest candidates of
      its own kind (one projection for both: they share no edge);
    * history: robots <- historical robots and <- historical goals (the h_rr' and h_r* terms of eq. 13)
      by MLP attention with Euclidean distances; historical robots <- their K nearest frontiers and
      targets (G_r'e, G_r'c; G_r'g over both without type awareness) by dot-product attention;
    * eq. 13: each node set adds its graphs' messages through its update MLP
      (:class:`~areasearch.models.blocks.NodeUpdate`).

    The robot-candidate score of eq. 9 is one per pair and head: G_rg normalises it over a robot's
    candidates and over a candidate's robots, G_re and G_rc over a robot's frontiers and its targets.
    """

    def __init__(self, cfg: NetworkConfig, last: bool = False) -> None:
        super().__init__()
        d, dh, a, m, dk, dv, hid = (
            cfg.node_dim, cfg.history_dim, cfg.attention_hidden, cfg.heads, cfg.key_dim, cfg.value_dim,
            cfg.update_hidden,
        )  # fmt: skip
        self.heads, self.cross_heads, self.key_dim, self.value_dim = m, cfg.cross_heads, dk, dv
        self.type_aware, self.history = cfg.type_aware, cfg.history
        self.typed = typed = 2 if cfg.type_aware else 1  # G_g [and G_e / G_c]
        robot_parts = {"qk": 2 * m * dk, "value": dv, "pair": a} | ({"past": a} if cfg.history else {})
        goal_parts = {"qk": 2 * typed * m * dk, "value": dv, "pair": a} | ({"key": m * dk} if cfg.history else {})
        self.robot_proj = Projections(d, robot_parts | {"own": hid})
        self.goal_proj = Projections(d, goal_parts | {"own": hid})
        self.pair_edge = nn.Linear(cfg.edge_dim, a, bias=False)  # the distance part of eq. 9's MLP
        self.pair_logits = nn.Linear(a, cfg.cross_heads)
        self.update_past = cfg.history and not last  # history features after the last round are not read
        self.normed, self.score_scale = cfg.norm == "pre-ln", float(cfg.score_scale)
        if self.normed:  # pre-LN: the round reads normalised features; the residual stream is left as it is
            self.robot_norm, self.goal_norm = nn.LayerNorm(d), nn.LayerNorm(d)
            if cfg.history:
                self.past_norm = nn.LayerNorm(dh)
        if cfg.history:
            mine = {"qk": 2 * m * dk, "own": hid} if self.update_past else {}
            query = {"query": typed * m * dk} if self.update_past else {}
            self.past_robot_proj = Projections(dh, mine | query | {"value": dv, "pair": a})
            self.past_goal_proj = Projections(dh, mine | {"value": dv, "pair": a})
            self.past_edge = nn.Linear(cfg.edge_dim, a, bias=False)
            self.past_logits = nn.Linear(a, cfg.cross_heads)
        if self.update_past:
            self.past_robot_update = NodeUpdate(dh, [dv, typed * dv], hid)  # G_r'; G_r'e [, G_r'c]
            self.past_goal_update = NodeUpdate(dh, [dv], hid)  # G_g'
        # robots: G_r, G_rg [, G_re, G_rc] [, historical robots, historical goals]; candidates: G_g [, G_e/c], G_rg
        self.robot_update = NodeUpdate(d, [(2 + 2 * cfg.type_aware + 2 * cfg.history) * dv], hid)
        self.goal_update = NodeUpdate(d, [typed * dv, dv], hid)

    def _norm(self, x: Tensor, which: str) -> Tensor:
        """The round's view of a node set's features: LayerNorm'ed (``pre-ln``) or as they are."""
        if not self.normed:
            return x
        ln = cast(nn.LayerNorm, getattr(self, which))
        return F.layer_norm(x, ln.normalized_shape, ln.weight, ln.bias, ln.eps)

    def _scores(self, q: Tensor, k: Tensor) -> tuple[Tensor, Tensor]:
        """(queries, keys) whose dot products are the attention logits: q . k / sqrt(dk), or with
        ``pre-ln`` cos(q, k) * score_scale (query-key normalisation: bounded scores)."""
        if not self.normed:
            return q * self.key_dim**-0.5, k
        return F.normalize(q, dim=-1) * self.score_scale, F.normalize(k, dim=-1)

    def forward(self, state: State, ctx: Context, step: int, probe: dict[str, float] | None = None) -> State:
        r, g, past = state
        m, dk, dv, typed = self.heads, self.key_dim, self.value_dim, self.typed
        b, nr = ctx.b, ctx.r
        if probe is not None:
            probe_features(probe, f"round{step}", r, g, ctx)
        rp, gp = self.robot_proj(self._norm(r, "robot_norm")), self.goal_proj(self._norm(g, "goal_norm"))

        # G_r, eqs. 6-8 (every robot of the decision)
        qk = rp["qk"].view(-1, 2, m, dk)
        robot_values = rp["value"].reshape(-1, m, dv // m)
        q, k = self._scores(qk[:, 0], qk[:, 1])
        to_r = [sparse_attention(q, k, robot_values, ctx.robot_rows, nr).view(b, nr, dv)]

        # G_g [and G_e / G_c], eqs. 6-8, 11: each candidate over its K nearest candidates [of its kind]
        qk = gp["qk"].view(-1, 2, typed * m, dk)
        values = gp["value"].view(-1, m, dv // m)
        q, k = self._scores(qk[:, 0], qk[:, 1])
        to_g = [sparse_attention(q, k, values, ctx.cand_rows, ctx.cand_groups).view(-1, typed * dv)]
        if probe is not None:
            _probe_scores(probe, f"round{step}", q, k, ctx.cand_rows)

        # eqs. 9-10, 12: G_rg both ways [and G_re, G_rc], one hidden layer over the robot-candidate pairs
        pair_edges = F.linear(ctx.pair_edges, self.pair_edge.weight)
        goal_pairs = padded(gp["pair"], ctx)
        out_r, out_g = cross_attention(
            pair_edges, ctx.pair_rows, rp["pair"], goal_pairs, self.pair_logits.weight, self.pair_logits.bias,
            ctx.kind, padded(gp["value"], ctx), rp["value"], typed, CAP,
        )  # fmt: skip
        if probe is not None:
            _probe_saturation(
                probe, f"round{step}", pair_edges, ctx.pair_rows, rp["pair"], goal_pairs, self.pair_logits
            )
        to_r.append(out_r.flatten(2))  # G_rg [, G_re, G_rc]
        assert out_g is not None
        to_g.append(packed(out_g.flatten(2), ctx))  # G_rg

        if self.history:
            assert past is not None and ctx.past_pair_rows is not None and ctx.past_edges is not None
            assert ctx.past_kind is not None
            n = ctx.n
            normed_past = self._norm(past, "past_norm")
            hp, qp = self.past_robot_proj(normed_past[:, :n]), self.past_goal_proj(normed_past[:, n:])
            past_values = torch.cat([hp["value"], qp["value"]], dim=1)  # (B, 2N, dv)
            out_past, _ = cross_attention(
                F.linear(ctx.past_edges, self.past_edge.weight), ctx.past_pair_rows, rp["past"],
                torch.cat([hp["pair"], qp["pair"]], dim=1), self.past_logits.weight, self.past_logits.bias,
                ctx.past_kind, past_values, None, 2, CAP,
            )  # fmt: skip
            to_r.append(out_past[:, :, 1:].flatten(2))  # h_rr', h_r* of eq. 13
            if self.update_past:
                assert ctx.past_rows is not None and ctx.past_cand_rows is not None
                qk = torch.cat([hp["qk"], qp["qk"]], dim=1).view(-1, 2, m, dk)  # G_r', G_g'
                q, k = self._scores(qk[:, 0], qk[:, 1])
                mine = sparse_attention(q, k, past_values.view(-1, m, dv // m), ctx.past_rows, 2 * n).view(b, 2 * n, dv)
                # G_r'e [, G_r'c]
                q, k = self._scores(hp["query"].reshape(-1, typed * m, dk), gp["key"].view(-1, m, dk))
                found = sparse_attention(q, k, values, ctx.past_cand_rows, n)
                robots_past = self.past_robot_update(
                    past[:, :n].flatten(0, 1),
                    hp["own"].flatten(0, 1),
                    [mine[:, :n].flatten(0, 1), found.view(-1, typed * dv)],
                )
                goals_past = self.past_goal_update(
                    past[:, n:].flatten(0, 1), qp["own"].flatten(0, 1), [mine[:, n:].flatten(0, 1)]
                )
                past = torch.cat([robots_past.view(b, n, -1), goals_past.view(b, n, -1)], dim=1)
        r = self.robot_update(r.flatten(0, 1), rp["own"].flatten(0, 1), [torch.cat(to_r, dim=-1).flatten(0, 1)])
        g = self.goal_update(g, gp["own"], to_g)
        return State(r.view(b, nr, -1), g, past)
