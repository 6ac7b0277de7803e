// SPDX-License-Identifier: Apache-2.0
// The cluster BVH the builder writes, checked from the object bytes alone: the documented
// shape (fewest nodes, whole leaves on the left, every active triangle in exactly one leaf),
// conservative boxes, splits at the median of the longest axis, and the same bytes on every
// build, for sizes 1..256 and for centroid sets that defeat quantized keys (all equal,
// near +-FLT_MAX, tiny, one far outlier), and the stored order of a reference build where no
// two centroids share a key.
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <numeric>
#include <random>
#include <string>
#include <vector>

namespace clastrace::engine {
namespace {

struct Mesh {
    std::vector<float> positions;
    std::vector<uint32_t> indices;
};

// One triangle near each center: its own three vertices while they fit in 256, else a
// strip over the centers (triangle t uses centers t, t+1, t+2, wrapping at 256 vertices).
Mesh triangles_at(const std::vector<std::array<float, 3>>& centers, float size) {
    Mesh m;
    const uint32_t n = uint32_t(centers.size());
    if (3 * n <= 256) {
        for (const auto& c : centers) {
            const uint32_t base = uint32_t(m.positions.size() / 3);
            const float offsets[3][3] = {{0, 0, 0}, {size, 0, 0}, {0, size, size}};
            for (const auto& o : offsets)
                for (int a = 0; a < 3; ++a)
                    m.positions.push_back(c[a] + o[a] * (c[a] == 0 ? 1.0f : std::fabs(c[a])));
            for (uint32_t v = 0; v < 3; ++v) m.indices.push_back(base + v);
        }
        return m;
    }
    const uint32_t vertices = std::min(n + 2, 256u);
    for (uint32_t v = 0; v < vertices; ++v)
        for (int a = 0; a < 3; ++a) m.positions.push_back(centers[std::min(v, n - 1)][a]);
    for (uint32_t t = 0; t < n; ++t)
        for (uint32_t k = 0; k < 3; ++k) m.indices.push_back((t + k) % vertices);
    return m;
}

BvhNode node_at(const std::vector<std::byte>& o, const ObjectHeader& h, uint32_t i) {
    BvhNode n;
    std::memcpy(&n, o.data() + h.nodes_offset + 8 * i, 8);
    return n;
}

// The decoding docs/engine-formats.md gives (the traversal's).
void node_box(const ObjectHeader& h, const BvhNode& n, float lo[3], float hi[3]) {
    for (int a = 0; a < 3; ++a) {
        const float step = (h.bounds_max[a] - h.bounds_min[a]) / 255.0f;
        lo[a] = n.qmin[a] == 0 ? h.bounds_min[a] : h.bounds_min[a] + float(n.qmin[a]) * step;
        hi[a] = n.qmax[a] == 255 ? h.bounds_max[a] : h.bounds_min[a] + float(n.qmax[a]) * step;
    }
}

struct Leaf {
    uint32_t first, count;
};

// Checks the tree of one object; returns its leaves in depth-first order.
std::vector<Leaf> check_tree(const std::vector<std::byte>& o, uint32_t active,
                             const std::string& what) {
    const HeaderCheck hc = read_object_header(o);
    EXPECT_TRUE(hc.header) << what << ": " << hc.error;
    if (!hc.header) return {};
    const ObjectHeader& h = *hc.header;
    EXPECT_EQ(h.node_count, 2 * ((active + 3) / 4) - 1) << what << ": the fewest nodes";
    std::vector<Leaf> leaves;
    std::vector<int> covered(active, 0);
    const bool unbounded = h.header_flags & kUnboundedNodes;
    // (node, triangles below it): depth first, left first.
    std::vector<uint32_t> stack = {0};
    std::vector<uint32_t> below(h.node_count, 0);
    while (!stack.empty()) {
        const uint32_t ni = stack.back();
        stack.pop_back();
        const BvhNode n = node_at(o, h, ni);
        float lo[3], hi[3];
        node_box(h, n, lo, hi);
        if (n.link & kLeafBit) {
            const Leaf leaf{uint32_t(n.link & 0xFF), uint32_t(((n.link >> 8) & 3) + 1)};
            leaves.push_back(leaf);
            for (uint32_t i = leaf.first; i < leaf.first + leaf.count; ++i) {
                if (i >= active) {
                    ADD_FAILURE() << what << ": leaf holds stored triangle " << i << " beyond the "
                                  << active << " active ones";
                    continue;
                }
                ++covered[i];
                if (unbounded) continue;
                const DecodedTriangle t = decode_triangle(o, h, i);
                for (int v = 0; v < 3; ++v)
                    for (int a = 0; a < 3; ++a) {
                        EXPECT_LE(lo[a], t.v[v][a])
                            << what << ": node " << ni << " box misses triangle " << i;
                        EXPECT_GE(hi[a], t.v[v][a])
                            << what << ": node " << ni << " box misses triangle " << i;
                    }
            }
            continue;
        }
        const uint32_t left = n.link & 0x3FF;
        stack.push_back(left + 1);
        stack.push_back(left);
    }
    for (uint32_t i = 0; i < active; ++i)
        EXPECT_EQ(covered[i], 1) << what << ": stored triangle " << i;
    // Depth-first leaves cover the stored order left to right, so every subtree is a range;
    // a left subtree holds whole leaves.
    uint32_t next = 0;
    for (const Leaf& l : leaves) {
        EXPECT_EQ(l.first, next) << what;
        next = l.first + l.count;
    }
    for (size_t k = 0; k + 1 < leaves.size(); ++k)
        EXPECT_EQ(leaves[k].count, 4u) << what << ": only the last leaf may be partial";
    return leaves;
}

std::vector<std::byte> build(const Mesh& m, const std::string& what) {
    ClusterBuilder b;
    std::vector<std::byte> out;
    std::vector<Finding> findings;
    EXPECT_TRUE(b.build_from_arrays(7, m.positions, m.indices, 0, 0, {}, out, findings)) << what;
    return out;
}

TEST(ClusterBvh, ShapeBoxesAndDeterminismForEverySize) {
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> u(-50.0f, 50.0f);
    for (uint32_t n = 1; n <= 256; ++n) {
        std::vector<std::array<float, 3>> centers(n);
        for (auto& c : centers) c = {u(rng), u(rng) * 0.3f, u(rng) * 0.01f};
        const Mesh m = triangles_at(centers, 0.01f);
        const std::string what = "random " + std::to_string(n);
        const auto o = build(m, what);
        check_tree(o, n, what);
        EXPECT_EQ(o, build(m, what)) << what << ": same input, same bytes";
    }
}

TEST(ClusterBvh, CentroidSetsThatDefeatQuantizedKeys) {
    std::vector<std::pair<std::string, std::vector<std::array<float, 3>>>> sets;
    {
        std::vector<std::array<float, 3>> same(200, {1.0f, 2.0f, 3.0f});
        sets.push_back({"all centroids equal", same});
    }
    {
        std::vector<std::array<float, 3>> outlier;
        for (int i = 0; i < 255; ++i)
            outlier.push_back({float(i) * 1e-4f, float(i % 7) * 1e-4f, 0.0f});
        outlier.push_back({1e6f, 0.0f, 0.0f});  // squeezes the rest into one key step
        sets.push_back({"one far outlier", outlier});
    }
    {
        std::vector<std::array<float, 3>> huge;
        for (int i = 0; i < 100; ++i)
            huge.push_back(
                {(i % 2 ? 1.0f : -1.0f) * 3.0e38f, float(i), -3.0e38f + float(i) * 1e36f});
        sets.push_back({"near +-FLT_MAX", huge});
    }
    {
        std::vector<std::array<float, 3>> tiny;
        for (int i = 0; i < 100; ++i)
            tiny.push_back({float(i) * 1e-40f, 1e-38f, -float(i) * 1e-39f});
        sets.push_back({"denormal", tiny});
    }
    for (const auto& [name, centers] : sets) {
        const Mesh m = triangles_at(centers, 1e-3f);
        const auto o = build(m, name);
        check_tree(o, uint32_t(centers.size()), name);
        EXPECT_EQ(o, build(m, name)) << name;
    }
}

// The stored order of the documented splits, for centroids that no key step holds two of
// (so the builder's key order is their order on every axis): a node splits along the longest
// extent of its centroids (x before y before z on a tie), the left child taking half of its
// leaves (rounded up), and a leaf keeps its parent's order along the split axis.
void reference_order(const std::vector<std::array<float, 3>>& c, std::vector<uint32_t> tris,
                     std::vector<uint32_t>& out) {
    if (tris.size() <= 4) {
        out.insert(out.end(), tris.begin(), tris.end());
        return;
    }
    int axis = 0;
    float best = 0.0f;
    for (int a = 0; a < 3; ++a) {
        const auto by_axis = [&](uint32_t x, uint32_t y) { return c[x][a] < c[y][a]; };
        const auto [lo, hi] = std::minmax_element(tris.begin(), tris.end(), by_axis);
        const float extent = c[*hi][a] - c[*lo][a];
        if (a == 0 || extent > best) {
            best = extent;
            axis = a;
        }
    }
    std::sort(tris.begin(), tris.end(),
              [&](uint32_t x, uint32_t y) { return c[x][axis] < c[y][axis]; });
    const size_t leaves = (tris.size() + 3) / 4, left = 4 * ((leaves + 1) / 2);
    reference_order(c, {tris.begin(), tris.begin() + ptrdiff_t(left)}, out);
    reference_order(c, {tris.begin() + ptrdiff_t(left), tris.end()}, out);
}

TEST(ClusterBvh, StoredOrderIsTheReferenceSplitsOnDistinctKeys) {
    // Point triangles (one vertex three times: the centroid is the vertex) at distinct integer
    // coordinates on each axis, so two centroids are at least 4 key steps (extent / 1024)
    // apart; the axes' scales differ, so the longest axis changes from node to node and every
    // kind of split (both children leaves, a leaf on the right, two nodes) reorders the other
    // two axes.
    std::mt19937 rng(23);
    const float scale[3] = {1.0f, 0.75f, 0.5625f};
    for (uint32_t n = 1; n <= 256; ++n) {
        std::vector<std::array<float, 3>> c(n);
        for (int a = 0; a < 3; ++a) {
            std::vector<uint32_t> coordinate(n);
            std::iota(coordinate.begin(), coordinate.end(), 0u);
            std::shuffle(coordinate.begin(), coordinate.end(), rng);
            for (uint32_t t = 0; t < n; ++t) c[t][a] = float(coordinate[t]) * scale[a];
        }
        Mesh m;
        for (uint32_t t = 0; t < n; ++t) {
            m.positions.insert(m.positions.end(), c[t].begin(), c[t].end());
            m.indices.insert(m.indices.end(), {t, t, t});
        }
        const std::string what = "distinct keys " + std::to_string(n);
        const auto o = build(m, what);
        check_tree(o, n, what);
        std::vector<uint32_t> tris(n), expected;
        std::iota(tris.begin(), tris.end(), 0u);
        if (n <= 4)  // a root leaf: its triangles along x
            std::sort(tris.begin(), tris.end(),
                      [&](uint32_t x, uint32_t y) { return c[x][0] < c[y][0]; });
        reference_order(c, tris, expected);
        const ObjectHeader h = *read_object_header(o).header;
        for (uint32_t i = 0; i < n; ++i)
            EXPECT_EQ(decode_triangle(o, h, i).original_index, expected[i])
                << what << ": stored triangle " << i;
    }
}

TEST(ClusterBvh, SplitsAtTheMedianOfTheLongestAxis) {
    // 64 triangles on a line along y, given in shuffled order: median splits along y put
    // triangles 4k..4k+3 (by y) into the k-th leaf from the left, whatever the input order.
    std::vector<uint32_t> by_input(64);
    for (uint32_t i = 0; i < 64; ++i) by_input[i] = i;
    std::shuffle(by_input.begin(), by_input.end(), std::mt19937(5));
    std::vector<std::array<float, 3>> centers;
    for (uint32_t y : by_input) centers.push_back({0.25f * float(y % 2), float(y), 0.1f});
    const Mesh m = triangles_at(centers, 0.01f);
    const auto o = build(m, "line");
    const auto leaves = check_tree(o, 64, "line");
    const ObjectHeader h = *read_object_header(o).header;
    ASSERT_EQ(leaves.size(), 16u);
    for (uint32_t k = 0; k < leaves.size(); ++k)
        for (uint32_t i = leaves[k].first; i < leaves[k].first + leaves[k].count; ++i) {
            const uint32_t y = by_input[decode_triangle(o, h, i).original_index];
            EXPECT_EQ(y / 4, k) << "leaf " << k << " holds the triangle at y " << y;
        }
}

}  // namespace
}  // namespace clastrace::engine
