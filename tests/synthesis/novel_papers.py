"""Papers written for the equation compiler's tests: never seen by the compiler's authors' tables (nothing of them
is in notation.yaml), run exactly as a real paper is."""

_GATENERF = r"""# GateNeRF: Gated Memory Radiance Fields for View Synthesis

## Abstract

We present GateNeRF, a neural radiance field whose backbone gates two embeddings of the position and keeps a memory
across training steps. Like NeRF, we use positional encoding of the sample positions, hierarchical sampling along
each ray and volume rendering of colour and density.

## 1 Introduction

Neural radiance fields represent a scene with a multilayer perceptron queried along camera rays.

## 3 Method

### 3.1 Gated embeddings

Two neural models map the encoded position to embeddings $\mathbf{h}_a$ and $\mathbf{h}_b$; {networks}. A gate
mixes them:

$$\mathbf{g} = \sigma(\mathbf{W}_g [\mathbf{h}_a, \mathbf{h}_b] + \mathbf{b}_g) \tag{1}$$

where $\mathbf{W}_g$ and $\mathbf{b}_g$ are the gate weight matrix and bias, respectively. The memory is updated from
the gate:

$$\mathbf{m} = \tanh(\mathbf{W}_m (\mathbf{g} \odot \mathbf{m}) + \mathbf{b}_m) \tag{2}$$

where {memory}. The backbone's output is

$$\mathbf{h}_{o} = [\mathbf{m} \odot \mathbf{h}_a, \mathbf{h}_b] \tag{3}$$

which feeds the density and colour heads.

## 4 Experiments

We train for 200k iterations with a learning rate of 5e-4 on the Blender dataset.
"""

GATENERF = _GATENERF.replace("{networks}", "each is an MLP of 2 layers with 32 hidden units").replace(
    "{memory}", r"$\mathbf{m} \in \mathbb{R}^{z \times h}$, with $z = 64$ rows and $h = 32$")
"""GateNeRF: a gated backbone with a memory (persistent state), its sizes stated."""
GATENERF_NO_WIDTH = _GATENERF.replace("{networks}", "each is a small MLP").replace(
    "{memory}", "the memory starts empty")
"""The same paper stating no width: a learned matrix's size is open."""

PROJNERF = r"""# ProjNeRF: Projected Features for Radiance Fields

## Abstract

We use positional encoding, hierarchical sampling and volume rendering as NeRF does.

## 3 Method

### 3.1 Projected features

The position is projected and gated:

$$\mathbf{h}_1 = \mathrm{ReLU}(\mathbf{W}_1 \mathbf{x} + \mathbf{b}_1) \tag{1}$$

$$\mathbf{h}_2 = \mathbf{h}_1 \odot \sigma(\mathbf{W}_2 \mathbf{h}_1 + \mathbf{b}_2) \tag{2}$$

where $\mathbf{W}_1$, $\mathbf{W}_2$ are weight matrices and the hidden features have 64 hidden units.
"""
"""A learned matrix applied to the backbone's own input, whose width is known only when the plugin is built."""

SPARSEFIELD = r"""# SparseField: Sparse Radiance Fields with a Pseudo-Huber Prior

## Abstract

We use positional encoding, hierarchical sampling and volume rendering as NeRF does.

## 3 Method

### 3.2 Sparsity regularization

We penalise density everywhere with a pseudo-Huber prior on the densities along each ray:

$$\mathcal{L}_{s} = \lambda \sum_{i} \left(\sqrt{1 + \frac{\sigma_i^2}{c}} - 1\right) \tag{3}$$

where $\lambda = 0.01$ and $c = 0.5$.
"""
"""A loss on the field's densities (a regulariser no card has: SNeRG's Cauchy prior would be a card's), its constants
stated in the text."""
