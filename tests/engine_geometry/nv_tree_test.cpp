// SPDX-License-Identifier: Apache-2.0
// The NV SAH tree builder (engine/src/nv_tree.cpp, issue 22): every tree it builds is valid
// (each item in exactly one leaf, leaves of 1..kNvMaxLeafSize items, every box containing
// what lies under it, children after their parent) on the bench's meshes and on inputs that
// collapse its bins, and the SAH object answers closest-hit rays at the same t as the
// independently built Morton object of the same triangles.
#include "nv_internal.h"
#include "nv_scene.h"

#include <clastrace/engine/nv_trace.h>
#include <clastrace/testsupport/mesh.h>
#include <clastrace/testsupport/rays.h>

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

namespace clastrace::engine {
namespace {

using nv::Box;
namespace ts = clastrace::testsupport;

bool contains(const NvNode& outer, const Box& inner) {
    if (!inner.valid()) return true;  // an empty or NaN item box has nothing to contain
    for (int a = 0; a < 3; ++a)
        if (!(outer.bounds_min[a] <= inner.lo[a] && inner.hi[a] <= outer.bounds_max[a]))
            return false;
    return true;
}

Box node_box(const NvNode& n) {
    return Box{{n.bounds_min[0], n.bounds_min[1], n.bounds_min[2]},
               {n.bounds_max[0], n.bounds_max[1], n.bounds_max[2]}};
}

// The first broken rule of `t` over `boxes`, or "" for a valid tree.
std::string tree_fault(const nv::Tree& t, const std::vector<Box>& boxes) {
    if (t.order.size() != boxes.size()) return "order has " + std::to_string(t.order.size());
    std::vector<int> seen(boxes.size(), 0);
    for (uint32_t id : t.order)
        if (id >= boxes.size() || seen[id]++) return "item " + std::to_string(id) + " repeated";
    std::vector<int> leaf_of(boxes.size(), 0);  // times each order position sits in a leaf
    for (size_t k = 0; k < t.nodes.size(); ++k) {
        const NvNode& n = t.nodes[k];
        const std::string at = "node " + std::to_string(k);
        if (n.count == 0) {
            if (k + 1 >= t.nodes.size() || n.first <= k + 1 || n.first >= t.nodes.size())
                return at + ": child index out of order";
            for (uint32_t c : {uint32_t(k + 1), n.first})
                if (!contains(n, node_box(t.nodes[c]))) return at + ": child box outside";
            continue;
        }
        if (n.count > kNvMaxLeafSize) return at + ": leaf of " + std::to_string(n.count);
        if (n.first + n.count > t.order.size()) return at + ": leaf range past the items";
        for (uint32_t i = n.first; i < n.first + n.count; ++i) {
            ++leaf_of[i];
            if (!contains(n, boxes[t.order[i]])) return at + ": item box outside";
        }
    }
    for (size_t i = 0; i < leaf_of.size(); ++i)
        if (leaf_of[i] != 1)
            return "position " + std::to_string(i) + " in " + std::to_string(leaf_of[i]) +
                   " leaves";
    return "";
}

std::vector<Box> triangle_boxes(const ts::TriangleMesh& m) {
    std::vector<Box> boxes;
    for (const auto& tri : m.triangles) {
        float v[9];
        for (int k = 0; k < 3; ++k)
            for (int a = 0; a < 3; ++a) v[3 * k + a] = m.positions[tri[k]][a];
        boxes.push_back(nv::triangle_box(v));
    }
    return boxes;
}

// triangle_box (SSE) keeps Box::grow_point's rule: a NaN coordinate is ignored, infinities
// count, and nothing past the 9 floats is read.
TEST(NvTriangleBox, EqualsGrowingByEachVertex) {
    const float nan = std::numeric_limits<float>::quiet_NaN(),
                inf = std::numeric_limits<float>::infinity();
    const float values[] = {0.0f, -1.5f, 2.0f, nan, inf, -inf, 1e30f, -3e-30f};
    for (int c = 0; c < 4096; ++c) {
        float v[10];
        for (int k = 0; k < 9; ++k) v[k] = values[(c * 7 + k * k * 3 + k * c / 5) % 8];
        v[9] = -123.0f;  // must not reach the box
        Box want = Box::empty();
        for (int k = 0; k < 3; ++k) want.grow_point(v + 3 * k);
        const Box got = nv::triangle_box(v);
        for (int a = 0; a < 3; ++a) {
            EXPECT_EQ(std::memcmp(&got.lo[a], &want.lo[a], 4), 0) << "case " << c << " axis " << a;
            EXPECT_EQ(std::memcmp(&got.hi[a], &want.hi[a], 4), 0) << "case " << c << " axis " << a;
        }
    }
}

TEST(NvSahTree, ValidOnTheBenchMeshes) {
    for (const ts::TriangleMesh& m :
         {ts::make_icosphere(5, 1.0f), ts::make_terrain(120, 120, 1),
          ts::make_random_soup(30000, 5, 1.0f, 0.05f), ts::make_torus(200, 100, 1.0f, 0.3f)}) {
        const std::vector<Box> boxes = triangle_boxes(m);
        EXPECT_EQ(tree_fault(nv::build_tree(boxes), boxes), "") << m.name;
    }
}

TEST(NvSahTree, ValidWhereTheBinsCollapse) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const Box unit{{-1, -1, -1}, {1, 1, 1}};
    std::vector<std::pair<std::string, std::vector<Box>>> cases;
    cases.push_back({"one item", {unit}});
    cases.push_back({"two items", {unit, Box{{2, 0, 0}, {3, 1, 1}}}});
    cases.push_back({"5 equal", std::vector<Box>(5, unit)});
    cases.push_back({"17 equal", std::vector<Box>(17, unit)});
    cases.push_back({"1e6 equal", std::vector<Box>(1000000, unit)});
    // Equal centroids, different sizes: every bin but one empty.
    std::vector<Box> nested;
    for (int i = 1; i <= 300; ++i) nested.push_back(Box{{-float(i), -1, -1}, {float(i), 1, 1}});
    cases.push_back({"nested", nested});
    // NaN and empty boxes (a triangle whose vertices are all NaN has an empty box) among
    // ordinary ones, in small and in binned ranges.
    for (size_t n : {6u, 40u, 5000u}) {
        std::vector<Box> mixed;
        for (size_t i = 0; i < n; ++i) {
            const float x = float(i);
            if (i % 5 == 1)
                mixed.push_back(Box{{nan, 0, 0}, {nan, 1, 1}});
            else if (i % 5 == 3)
                mixed.push_back(Box::empty());
            else
                mixed.push_back(Box{{x, 0, 0}, {x + 1, 1, 1}});
        }
        cases.push_back({"NaN and empty among " + std::to_string(n), mixed});
    }
    for (const auto& [name, boxes] : cases)
        EXPECT_EQ(tree_fault(nv::build_tree(boxes), boxes), "") << name;
}

// Items under each node (children come after their parent: one pass from the back).
std::vector<uint32_t> subtree_items(const nv::Tree& t) {
    std::vector<uint32_t> items(t.nodes.size(), 0);
    for (size_t k = t.nodes.size(); k-- > 0;) {
        const NvNode& n = t.nodes[k];
        items[k] = n.count != 0 ? n.count : items[k + 1] + items[n.first];
    }
    return items;
}

// Bottom levels (TreeLevel::kBottom, the default) never split a range that fits a leaf: the
// traversal merges such subtrees into one leaf anyway. Top levels (kTop) still let the SAH
// split them, which on these meshes it does.
TEST(NvSahTree, BottomLevelsEndAtFullLeaves) {
    for (const ts::TriangleMesh& m :
         {ts::make_icosphere(4, 1.0f), ts::make_random_soup(20000, 7, 1.0f, 0.05f)}) {
        const std::vector<Box> boxes = triangle_boxes(m);
        const nv::Tree full = nv::build_tree(boxes);
        ASSERT_EQ(tree_fault(full, boxes), "") << m.name;
        const std::vector<uint32_t> full_items = subtree_items(full);
        size_t small_inner = 0;
        for (size_t k = 0; k < full.nodes.size(); ++k)
            small_inner += full.nodes[k].count == 0 && full_items[k] <= kNvMaxLeafSize;
        EXPECT_EQ(small_inner, 0u) << m.name;
        const nv::Tree sah = nv::build_tree(boxes, nv::TreeQuality::kSah, nv::TreeLevel::kTop);
        ASSERT_EQ(tree_fault(sah, boxes), "") << m.name;
        const std::vector<uint32_t> sah_items = subtree_items(sah);
        small_inner = 0;
        for (size_t k = 0; k < sah.nodes.size(); ++k)
            small_inner += sah.nodes[k].count == 0 && sah_items[k] <= kNvMaxLeafSize;
        EXPECT_GT(small_inner, 0u) << m.name;
    }
}

// Builds running at once on several threads (each thread keeps its working arrays between
// builds; a thread waiting inside one build may run another's task) give the trees a lone
// build gives.
TEST(NvSahTree, ConcurrentBuildsEqualLoneBuilds) {
    std::vector<std::vector<Box>> sets;
    for (int k = 0; k < 12; ++k)
        sets.push_back(triangle_boxes(ts::make_random_soup(18000 + 1500 * k, 40 + k, 1.0f, 0.05f)));
    for (nv::TreeQuality quality : {nv::TreeQuality::kSah, nv::TreeQuality::kMorton}) {
        std::vector<nv::Tree> alone;
        {
            tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
            for (const auto& boxes : sets) alone.push_back(nv::build_tree(boxes, quality));
        }
        std::vector<nv::Tree> together(sets.size());
        tbb::task_arena(4).execute([&] {
            tbb::parallel_for(size_t(0), sets.size(),
                              [&](size_t k) { together[k] = nv::build_tree(sets[k], quality); });
        });
        for (size_t k = 0; k < sets.size(); ++k) {
            EXPECT_EQ(together[k].order, alone[k].order) << "set " << k;
            ASSERT_EQ(together[k].nodes.size(), alone[k].nodes.size()) << "set " << k;
            EXPECT_EQ(std::memcmp(together[k].nodes.data(), alone[k].nodes.data(),
                                  alone[k].nodes.size() * sizeof(NvNode)),
                      0)
                << "set " << k;
        }
    }
}

// Closest t through the SAH object and the Morton object of the same mesh, on random rays:
// the tree must never change which t a ray finds.
TEST(NvSahTree, ClosestHitsEqualTheMortonTreesOnRandomRays) {
    for (const ts::TriangleMesh& m :
         {ts::make_icosphere(4, 1.0f), ts::make_random_soup(20000, 7, 1.0f, 0.05f)}) {
        nvtest::BlasSpec spec;
        spec.geometries.push_back({m, {}, VK_GEOMETRY_OPAQUE_BIT_NV});
        auto sah = nvtest::build_scene({spec}, {nvtest::InstanceSpec{}});
        auto morton = nvtest::build_scene({spec}, {nvtest::InstanceSpec{}},
                                          VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV);
        auto a = NvScene::open_bottom(sah->world.memory, sah->blas[0].address, nullptr);
        auto b = NvScene::open_bottom(morton->world.memory, morton->blas[0].address, nullptr);
        ASSERT_TRUE(a && b);
        size_t hits = 0, differ = 0;
        for (const ts::TestRay& r : ts::random_rays(ts::bounds_of(m), 20000, 11)) {
            const Ray ray{{r.origin[0], r.origin[1], r.origin[2]},
                          0,
                          {r.direction[0], r.direction[1], r.direction[2]},
                          r.tmax};
            const NvHit ha = a->closest(ray, 0, 0xFF), hb = b->closest(ray, 0, 0xFF);
            hits += ha.hit;
            differ += ha.hit != hb.hit || (ha.hit && ha.t != hb.t);
        }
        EXPECT_GT(hits, 1000u) << m.name;
        EXPECT_EQ(differ, 0u) << m.name;
    }
}

}  // namespace
}  // namespace clastrace::engine
