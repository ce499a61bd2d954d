"""Transformer pieces of MSNET written with plain matmul/softmax (no fused attention kernels).

``torch.nn.MultiheadAttention`` and ``scaled_dot_product_attention`` export to ONNX as fused
or opset-specific patterns; these modules export to MatMul, Add, Mul, Reshape, Transpose,
Softmax, LayerNormalization and Erf only, all parsed by TensorRT. Their matmuls (projections,
``q @ kᵀ`` and ``attn @ v``) are ordinary ``aten.mm``/``aten.bmm`` calls, so
``torch.utils.flop_counter.FlopCounterMode`` (``slimseg info``) counts all of them.
"""

from __future__ import annotations

import torch
from torch import nn


class Attention(nn.Module):
    """Multi-head attention ``softmax(q kᵀ / √d) v`` over token sequences.

    ``query [B, Nq, C]``, ``memory [B, Nk, C]`` (``None``: self-attention) → ``[B, Nq, C]``.
    ``query_pos`` / ``memory_pos`` (same shapes, optional) are added to queries and keys only
    (DETR convention), never to the values.
    """

    def __init__(self, dim: int, heads: int, dropout: float = 0.0) -> None:
        super().__init__()
        if dim % heads:
            raise ValueError(f"dim {dim} is not divisible by heads {heads}")
        self.heads = heads
        self.head_dim = dim // heads
        self.scale = self.head_dim**-0.5
        self.q = nn.Linear(dim, dim)
        self.k = nn.Linear(dim, dim)
        self.v = nn.Linear(dim, dim)
        self.proj = nn.Linear(dim, dim)
        self.drop = nn.Dropout(dropout)

    def _split(self, x: torch.Tensor) -> torch.Tensor:
        b, n, _ = x.shape
        return x.reshape(b, n, self.heads, self.head_dim).transpose(1, 2)  # [B, h, N, d]

    def forward(
        self,
        query: torch.Tensor,
        memory: torch.Tensor | None = None,
        query_pos: torch.Tensor | None = None,
        memory_pos: torch.Tensor | None = None,
    ) -> torch.Tensor:
        if memory is None:
            memory, memory_pos = query, query_pos
        q_in = query if query_pos is None else query + query_pos
        k_in = memory if memory_pos is None else memory + memory_pos
        q = self._split(self.q(q_in)) * self.scale
        k = self._split(self.k(k_in))
        v = self._split(self.v(memory))
        attn = torch.matmul(q, k.transpose(-2, -1)).softmax(dim=-1)  # [B, h, Nq, Nk]
        out = torch.matmul(self.drop(attn), v)  # [B, h, Nq, d]
        b, _, n, _ = out.shape
        return self.proj(out.transpose(1, 2).reshape(b, n, self.heads * self.head_dim))


class MLP(nn.Module):
    """Linear → GELU → dropout → Linear: ``[..., C] → [..., C_out]``."""

    def __init__(self, dim: int, hidden: int, out: int | None = None, dropout: float = 0.0) -> None:
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.act = nn.GELU()
        self.drop = nn.Dropout(dropout)
        self.fc2 = nn.Linear(hidden, out or dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.drop(self.act(self.fc1(x))))


class EncoderBlock(nn.Module):
    """Pre-norm ViT block: ``x + MHSA(LN(x))``, then ``x + MLP(LN(x))``; ``[B, N, C]``."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float, dropout: float = 0.0) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.attn = Attention(dim, heads, dropout)
        self.norm2 = nn.LayerNorm(dim)
        self.mlp = MLP(dim, round(dim * mlp_ratio), dropout=dropout)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.drop(self.attn(self.norm1(x)))
        return x + self.drop(self.mlp(self.norm2(x)))


class DecoderLayer(nn.Module):
    """Pre-norm Transformer decoder layer over class queries.

    ``queries [B, Q, C]`` attend to each other, then to ``memory [B, N, C]`` (cross-attention,
    ``memory_pos`` added to its keys), then an MLP; each with a residual. Returns ``[B, Q, C]``.
    """

    def __init__(self, dim: int, heads: int, mlp_ratio: float, dropout: float = 0.0) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.self_attn = Attention(dim, heads, dropout)
        self.norm2 = nn.LayerNorm(dim)
        self.cross_attn = Attention(dim, heads, dropout)
        self.norm3 = nn.LayerNorm(dim)
        self.mlp = MLP(dim, round(dim * mlp_ratio), dropout=dropout)
        self.drop = nn.Dropout(dropout)

    def forward(
        self,
        queries: torch.Tensor,
        query_pos: torch.Tensor,
        memory: torch.Tensor,
        memory_pos: torch.Tensor,
    ) -> torch.Tensor:
        x = queries
        h = self.norm1(x)
        x = x + self.drop(self.self_attn(h, None, query_pos, None))
        x = x + self.drop(self.cross_attn(self.norm2(x), memory, query_pos, memory_pos))
        return x + self.drop(self.mlp(self.norm3(x)))
