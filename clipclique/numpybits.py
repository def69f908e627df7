"""numpy's and OpenBLAS's arithmetic written out for compiled code, to the bit: a kernel that replaces a numpy
call must add in the order numpy adds, or results move in their last bits (and the results digest with them).

One place for what several modules' kernels share: numpy's pairwise sum, np.maximum's rule and the maximum of an
array by it, the fused multiply-add that OpenBLAS's dgemm chains for small matrices (from +0, one per term in
order), and a short span of integers sorted in place."""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import intrinsic


@njit(cache=True)
def pairwise_sum(values: np.ndarray, start: int, stop: int, zero):
    """values[start: stop].sum() as numpy adds a contiguous array, to the bit: in order below 8 values, else in
    8 running sums combined pairwise then the rest in order, halves of a multiple of 8 above 128 values (numpy's
    recursion walked with a stack of its own: a recursive kernel's numba cache fails to link into a caller compiled
    later, "Symbol not found")."""
    if stop - start <= 128:
        return _block_sum(values, start, stop, zero)
    starts, stops, halves_done = np.empty(64, np.int64), np.empty(64, np.int64), np.zeros(64, np.int64)
    sums = np.full(64, np.zeros(1, values.dtype)[0] + zero)  # the type numpy's recursion returns: both unified
    starts[0], stops[0] = start, stop
    top, found = 0, 0
    while top >= 0:
        first, last = starts[top], stops[top]
        if last - first <= 128:
            sums[found] = _block_sum(values, first, last, zero)
            found += 1
            top -= 1
            continue
        half = (last - first) // 2
        half -= half % 8
        if halves_done[top] == 2:  # both halves summed: left + right, as numpy's recursion returns
            found -= 1
            sums[found - 1] = sums[found - 1] + sums[found]
            top -= 1
            continue
        halves_done[top] += 1
        starts[top + 1], stops[top + 1], halves_done[top + 1] = ((first, first + half, 0) if halves_done[top] == 1
                                                                  else (first + half, last, 0))
        top += 1
    return sums[0]


@njit(cache=True, inline="always")
def _block_sum(values: np.ndarray, start: int, stop: int, zero):
    """numpy's pairwise sum of at most 128 values."""
    count = stop - start
    if count < 8:
        total = zero
        for i in range(start, stop):
            total += values[i]
        return total
    partial = values[start: start + 8].copy()
    end = stop - count % 8
    for i in range(start + 8, end, 8):
        for j in range(8):
            partial[j] += values[i + j]
    total = ((partial[0] + partial[1]) + (partial[2] + partial[3])) + ((partial[4] + partial[5])
                                                                      + (partial[6] + partial[7]))
    for i in range(end, stop):
        total += values[i]
    return total


@njit(cache=True, inline="always")
def maximum(a: float, b: float) -> float:
    """np.maximum(a, b) of two numbers: NaN where either is, else the larger (`a` where they tie)."""
    return a if a >= b or np.isnan(a) else b


@njit(cache=True, inline="always")
def largest(values: np.ndarray) -> float:
    """values.max() of a non-empty 1-D array: `maximum` folded over it in order (NaN where any value is NaN)."""
    result = values[0]
    for i in range(1, len(values)):
        result = maximum(result, values[i])
    return result


@intrinsic
def fma(typingctx, a, b, c):
    """a * b + c rounded once (LLVM's fma: the machine's instruction, as OpenBLAS's kernels use it)."""
    def codegen(context, builder, signature, args):
        return builder.fma(*args)
    return types.float64(types.float64, types.float64, types.float64), codegen


@njit(cache=True, inline="always")
def sort_span(values: np.ndarray, start: int, stop: int) -> None:
    """values[start: stop].sort() of integers (any sort orders them alike) by an insertion sort in place: a clique's
    dozen members, where a view's sort costs its reference counts and numba's quicksort setup (inlined into its
    callers, so the array is not counted in and out either)."""
    for i in range(start + 1, stop):
        value = values[i]
        j = i
        while j > start and values[j - 1] > value:
            values[j] = values[j - 1]
            j -= 1
        values[j] = value
