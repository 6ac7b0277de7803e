// SPDX-License-Identifier: Apache-2.0
// The binned SAH core (Wald 2007) of the engine's two tree builders, the cluster BLAS
// (blas_build.cpp) and the NV trees (nv_tree.cpp). Each builder bins its items its own way
// (scalar or SSE, its own bin mapping); both choose their splits here, with their
// parameters, and both grow their trees with the one top-down recursion below, which writes
// each builder's node format through the node emitter the builder provides and lays the
// nodes out in the builder's NodeLayout.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include <tbb/parallel_invoke.h>

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
    Cost cost =
        std::numeric_limits<Cost>::infinity();  // area(left) * n(left) + area(right) * n(right)
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
SahSplit<Cost> cheapest_split(int bins, const bool usable[3], BoxAt box_at, CountAt count_at,
                              const BinBox& empty, Area area) {
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
            const Cost cost =
                Cost(area(acc)) * Cost(n) + right_area[k + 1] * Cost(right_count[k + 1]);
            if (cost < best.cost) best = SahSplit<Cost>{a, k, cost};
        }
    }
    return best;
}

// Where a tree's nodes lie in their array. Both layouts are depth first, root at the
// subtree's first index; they differ in where an inner node's children go.
enum class NodeLayout {
    kSiblingPairs,  // both children side by side, taken when their parent splits; link = left child
    kPreorder,      // a node, its left subtree, then its right; left = node + 1, link = right child
};

// Appends a kPreorder subtree built with its root at index 0: its links shift by where it
// lands.
template <class Emitter, class Node>
void splice_preorder(const Emitter& emitter, std::vector<Node>& out, const std::vector<Node>& sub) {
    const uint32_t base = uint32_t(out.size());
    out.insert(out.end(), sub.begin(), sub.end());
    for (size_t k = base; k < out.size(); ++k)
        if (emitter.is_inner(out[k])) emitter.link(out[k], emitter.linked(out[k]) + base);
}

// The top-down build of one tree over ranges of items (Embree's and bvh v2's top-down
// builders are the models). The builder provides:
//   Range: a node's items with their bounds; count() is how many;
//   Splitter: bool split(const Range&, int depth, Range* left, Range* right) const, false
//     for a leaf (it may reorder the items of the range it splits; ranges split concurrently
//     are disjoint);
//   Emitter (the node emitter), writing its node format:
//     using Node; void leaf(Node&, const Range&); void inner(Node&, const Range&);
//     void link(Node& inner, uint32_t child) (the child its format names, by NodeLayout);
//     uint32_t linked(const Node&) and bool is_inner(const Node&) (to move subtrees).
// Ranges of at least parallel_from items build their halves as TBB tasks into their own
// arrays, spliced into the layout the sequential build gives: the bytes depend only on the
// items, never on the thread count or on parallel_from.
template <NodeLayout Layout, class Range, class Splitter, class Emitter>
class TopDownBuilder {
public:
    using Node = typename Emitter::Node;

    TopDownBuilder(const Splitter& splitter, const Emitter& emitter, uint32_t parallel_from)
        : splitter_(splitter), emitter_(emitter), parallel_from_(parallel_from) {}

    // Appends the tree of `root` to `out`, its root at out.size().
    void append(std::vector<Node>& out, const Range& root, int depth) const {
        if (root.count() < parallel_from_) return append_sequential(out, root, depth);
        const uint32_t node = uint32_t(out.size());
        out.emplace_back();
        Range left, right;
        if (!splitter_.split(root, depth, &left, &right)) return emitter_.leaf(out[node], root);
        emitter_.inner(out[node], root);
        std::vector<Node> left_nodes, right_nodes;
        left_nodes.reserve(2 * size_t(left.count()));
        right_nodes.reserve(2 * size_t(right.count()));
        tbb::parallel_invoke([&] { append(left_nodes, left, depth + 1); },
                             [&] { append(right_nodes, right, depth + 1); });
        if constexpr (Layout == NodeLayout::kSiblingPairs) {
            const uint32_t first = uint32_t(out.size());
            out.resize(out.size() + 2);
            emitter_.link(out[node], first);
            splice_pair_child(out, left_nodes, first);
            splice_pair_child(out, right_nodes, first + 1);
        } else {
            splice_preorder(emitter_, out, left_nodes);
            emitter_.link(out[node], uint32_t(out.size()));
            splice_preorder(emitter_, out, right_nodes);
        }
    }

private:
    // One pending node: for kSiblingPairs the index its parent took for it; for kPreorder the
    // inner node to link to it when it lands (kNoParent: a left child or the root).
    struct Pending {
        Range range;
        uint32_t slot;
        int depth;
    };
    static constexpr uint32_t kNoParent = ~0u;

    // Depth first with an explicit stack (no recursion depth limit), left child first.
    void append_sequential(std::vector<Node>& out, const Range& root, int depth) const {
        std::vector<Pending> stack;
        if constexpr (Layout == NodeLayout::kSiblingPairs) {
            stack.push_back({root, uint32_t(out.size()), depth});
            out.emplace_back();
        } else {
            stack.push_back({root, kNoParent, depth});
        }
        while (!stack.empty()) {
            const Pending p = stack.back();
            stack.pop_back();
            uint32_t node = p.slot;
            if constexpr (Layout == NodeLayout::kPreorder) {
                node = uint32_t(out.size());
                out.emplace_back();
                if (p.slot != kNoParent) emitter_.link(out[p.slot], node);
            }
            Range left, right;
            if (!splitter_.split(p.range, p.depth, &left, &right)) {
                emitter_.leaf(out[node], p.range);
                continue;
            }
            emitter_.inner(out[node], p.range);
            if constexpr (Layout == NodeLayout::kSiblingPairs) {
                const uint32_t first = uint32_t(out.size());
                out.resize(out.size() + 2);
                emitter_.link(out[node], first);
                stack.push_back({right, first + 1, p.depth + 1});
                stack.push_back({left, first, p.depth + 1});
            } else {
                stack.push_back({right, node, p.depth + 1});
                stack.push_back({left, kNoParent, p.depth + 1});
            }
        }
    }

    // A child subtree built with its root at index 0 (kSiblingPairs): the root goes to the
    // slot its parent took, the rest after everything already laid out.
    void splice_pair_child(std::vector<Node>& out, const std::vector<Node>& sub,
                           uint32_t root_at) const {
        const uint32_t rest = uint32_t(out.size());
        auto moved = [&](uint32_t k) { return k == 0 ? root_at : rest + k - 1; };
        out.resize(rest + sub.size() - 1);
        for (uint32_t k = 0; k < sub.size(); ++k) {
            Node n = sub[k];
            if (emitter_.is_inner(n)) emitter_.link(n, moved(emitter_.linked(n)));
            out[moved(k)] = n;
        }
    }

    const Splitter& splitter_;
    Emitter emitter_;
    uint32_t parallel_from_;
};

}  // namespace clastrace::engine::geometry
