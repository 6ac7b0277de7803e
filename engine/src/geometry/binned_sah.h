// The binned SAH core (Wald 2007) of the engine's two tree builders, the cluster BLAS
// (blas_build.cpp) and the NV trees (nv_tree.cpp). Each builder bins its items its own way
// (scalar or SSE, its own bin mapping) and lays out its own nodes; both choose their splits
// here, with their parameters, so the split choice is one piece of code.
#ifndef CLASTRACE_ENGINE_GEOMETRY_BINNED_SAH_H
#define CLASTRACE_ENGINE_GEOMETRY_BINNED_SAH_H

#include <cstdint>
#include <limits>

namespace clastrace::engine::geometry {

// A builder's SAH parameters. The costs are relative: a leaf of n items costs
// n * intersection_cost, a split traversal_cost plus its children, each weighted by the
// fraction of the parent's area it covers.
struct SahParams {
  int max_bins;              // per axis
  double traversal_cost;     // visiting an interior node
  double intersection_cost;  // testing one item (for the cluster BLAS: descending into a CLAS)
  uint32_t max_leaf_size;
};

template <class Cost>
struct SahSplit {
  int axis = -1;  // -1: no axis could be split (every usable axis has all items in one bin)
  int bin = 0;    // items in bins 0..bin go left
  Cost cost = std::numeric_limits<Cost>::infinity();  // area(left) * n(left) + area(right) * n(right)
};

// The cheapest split "bins 0..k left, the rest right" over the usable axes of `bins` bins
// per axis: per axis one sweep from the right (areas and counts of bins k..bins-1), one from
// the left. Costs are evaluated in Cost (the builders keep their own precision); a split with
// an empty side is never taken; only a strictly cheaper split replaces the best, so ties go
// to the lower axis, then the lower bin.
//   box_at(axis, k): the bounds of bin k (a type with grow(const BinBox&));
//   count_at(axis, k): its item count; empty: the empty BinBox;
//   area(box): the half area of a non-empty box, in Cost.
template <class Cost, int MaxBins, class BinBox, class BoxAt, class CountAt, class Area>
SahSplit<Cost> cheapest_split(int bins, const bool usable[3], BoxAt box_at, CountAt count_at, const BinBox& empty,
                              Area area) {
  SahSplit<Cost> best;
  for (int a = 0; a < 3; ++a) {
    if (!usable[a]) continue;
    Cost right_area[MaxBins];
    uint32_t right_count[MaxBins];
    BinBox acc = empty;
    uint32_t n = 0;
    for (int k = bins - 1; k > 0; --k) {
      acc.grow(box_at(a, k));
      n += count_at(a, k);
      right_area[k] = n ? Cost(area(acc)) : Cost(0);
      right_count[k] = n;
    }
    acc = empty;
    n = 0;
    for (int k = 0; k < bins - 1; ++k) {
      acc.grow(box_at(a, k));
      n += count_at(a, k);
      if (n == 0 || right_count[k + 1] == 0) continue;
      const Cost cost = Cost(area(acc)) * Cost(n) + right_area[k + 1] * Cost(right_count[k + 1]);
      if (cost < best.cost) best = SahSplit<Cost>{a, k, cost};
    }
  }
  return best;
}

}  // namespace clastrace::engine::geometry

#endif
