// SPDX-License-Identifier: Apache-2.0
// The binned-SAH core's top-down builder (engine/src/geometry/binned_sah.h) on a toy range
// splitter and node emitter: each NodeLayout puts the nodes where its format says, and the
// parallel build (its subtrees spliced) lays out the same array as the sequential one.
#include "geometry/binned_sah.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <vector>

namespace {

using clastrace::engine::geometry::NodeLayout;
using clastrace::engine::geometry::TopDownBuilder;

struct ToyRange {
    uint32_t begin = 0, end = 0;
    uint32_t count() const { return end - begin; }
};

struct ToyNode {
    uint32_t first = 0;
    uint32_t count = 0;  // 0: inner
    bool operator==(const ToyNode&) const = default;
};

// Leaves of one item; a split leaves count / divisor items on the left (at least one).
struct ToySplitter {
    uint32_t divisor = 2;
    bool split(const ToyRange& r, int /*depth*/, ToyRange* left, ToyRange* right) const {
        if (r.count() <= 1) return false;
        const uint32_t mid = r.begin + std::max(1u, r.count() / divisor);
        *left = {r.begin, mid};
        *right = {mid, r.end};
        return true;
    }
};

struct ToyEmitter {
    using Node = ToyNode;
    void leaf(Node& n, const ToyRange& r) const { n = {r.begin, r.count()}; }
    void inner(Node& n, const ToyRange&) const { n.count = 0; }
    void link(Node& n, uint32_t child) const { n.first = child; }
    uint32_t linked(const Node& n) const { return n.first; }
    bool is_inner(const Node& n) const { return n.count == 0; }
};

template <NodeLayout Layout>
std::vector<ToyNode> build(uint32_t items, uint32_t divisor, uint32_t parallel_from) {
    const ToySplitter splitter{divisor};
    std::vector<ToyNode> nodes;
    TopDownBuilder<Layout, ToyRange, ToySplitter, ToyEmitter>(splitter, ToyEmitter{}, parallel_from)
        .append(nodes, ToyRange{0, items}, 0);
    return nodes;
}

constexpr uint32_t kNever = ~0u;  // parallel_from: build everything on the calling thread

TEST(TopDownBuilder, SiblingPairsPutBothChildrenTogetherAndLinkTheLeftOne) {
    // [0,5) -> [0,2) [2,5); [0,2) -> [0,1) [1,2); [2,5) -> [2,3) [3,5); [3,5) -> [3,4) [4,5).
    const std::vector<ToyNode> expected{{1, 0}, {3, 0}, {5, 0}, {0, 1}, {1, 1},
                                        {2, 1}, {7, 0}, {3, 1}, {4, 1}};
    EXPECT_EQ(build<NodeLayout::kSiblingPairs>(5, 2, kNever), expected);
    EXPECT_EQ(build<NodeLayout::kSiblingPairs>(5, 2, 2), expected);  // every split spliced
}

TEST(TopDownBuilder, PreorderPutsTheLeftSubtreeNextAndLinksTheRightChild) {
    const std::vector<ToyNode> expected{{4, 0}, {3, 0}, {0, 1}, {1, 1}, {6, 0},
                                        {2, 1}, {8, 0}, {3, 1}, {4, 1}};
    EXPECT_EQ(build<NodeLayout::kPreorder>(5, 2, kNever), expected);
    EXPECT_EQ(build<NodeLayout::kPreorder>(5, 2, 2), expected);
}

TEST(TopDownBuilder, ParallelSubtreesSpliceIntoTheSequentialLayout) {
    // Uneven splits, so the spliced subtrees differ in size at every level.
    for (uint32_t parallel_from : {2u, 3u, 17u, 100u}) {
        EXPECT_EQ(build<NodeLayout::kSiblingPairs>(1000, 3, parallel_from),
                  build<NodeLayout::kSiblingPairs>(1000, 3, kNever))
            << parallel_from;
        EXPECT_EQ(build<NodeLayout::kPreorder>(1000, 3, parallel_from),
                  build<NodeLayout::kPreorder>(1000, 3, kNever))
            << parallel_from;
    }
}

}  // namespace
