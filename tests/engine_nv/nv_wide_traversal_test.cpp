// SPDX-License-Identifier: Apache-2.0
// The NV traversal's 4-wide layout and SIMD box test (engine/src/nv_wide_tree.h) against the
// plain answer (NvScene::closest_exhaustive: every primitive tested, no box): the same hit,
// t, instance, geometry, primitive, u, v and facing for every ray, in both traversal modes,
// over plain meshes, rays that graze the boxes (aimed at vertices and edges, the points that
// lie on leaf boxes' faces), axis-parallel rays, and the extremes (huge and tiny coordinates,
// small triangles far away, NaN and degenerate triangles, scaled, mirrored and rotated
// instances). A box test that rounds a bound inward culls the grazing rays' hits. The
// quantized nodes (one cache line each) are also checked box by box: every dequantized box
// contains the float box it stands for.
// The traversal tests run on both paths (nv_wide_tree.h, SimdPath): 8-wide nodes with the AVX2
// box test and 4-wide nodes with the SSE one, forced through the test hook; on a CPU without
// AVX2 both runs take the SSE path.
#include "nv_scene.h"
#include "nv_wide_tree.h"

#include <clastrace/testsupport/rays.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <sstream>

namespace clastrace::nvtest {
namespace {

constexpr eng::TraversalMode kModes[] = {eng::TraversalMode::kDouble, eng::TraversalMode::kFloat32};

BlasSpec one_mesh(ts::TriangleMesh m) {
    BlasSpec s;
    s.geometries.push_back({std::move(m), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    return s;
}

ts::TriangleMesh scaled(ts::TriangleMesh m, float scale, float offset) {
    for (auto& p : m.positions)
        for (float& c : p) c = c * scale + offset;
    return m;
}

std::string describe(const eng::NvHit& h) {
    std::ostringstream s;
    s.precision(9);
    if (!h.hit) return "miss";
    s << "t=" << h.t << " instance=" << h.instance_index << " geometry=" << h.geometry_index
      << " primitive=" << h.primitive_index << " u=" << h.u << " v=" << h.v
      << " kind=" << h.hit_kind;
    return s.str();
}

bool same(const eng::NvHit& a, const eng::NvHit& b) {
    if (a.hit != b.hit) return false;
    if (!a.hit) return true;
    return a.t == b.t && a.instance_index == b.instance_index &&
           a.geometry_index == b.geometry_index && a.primitive_index == b.primitive_index &&
           a.u == b.u && a.v == b.v && a.hit_kind == b.hit_kind;
}

// Random rays through the mesh's box, rays from random origins aimed at every `stride`-th
// vertex and edge midpoint (grazing the leaf boxes those points bound), and axis-parallel
// rays aimed at vertices (zero direction components). `back` > 0: every origin moved that far
// back along its ray (the interval with it), to see small triangles from far away.
std::vector<eng::Ray> rays_for(const ts::TriangleMesh& m, size_t random_count, uint64_t seed,
                               float back = 0.0f) {
    std::vector<eng::Ray> rays;
    const ts::Bounds b = ts::bounds_of(m);
    for (const auto& t : ts::random_rays(b, random_count, seed))
        rays.push_back(eng::Ray{{t.origin[0], t.origin[1], t.origin[2]},
                                t.tmin,
                                {t.direction[0], t.direction[1], t.direction[2]},
                                t.tmax});
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> unit(-1.0, 1.0);
    float extent = 0.0f;
    for (int a = 0; a < 3; ++a) extent = std::max(extent, b.hi[a] - b.lo[a]);
    const size_t stride = std::max<size_t>(1, m.triangles.size() / 400);
    for (size_t i = 0; i < m.triangles.size(); i += stride) {
        const auto& tri = m.triangles[i];
        const auto& p0 = m.positions[tri[0]];
        const auto& p1 = m.positions[tri[1]];
        float targets[2][3];
        for (int a = 0; a < 3; ++a) {
            targets[0][a] = p0[a];
            targets[1][a] = float((double(p0[a]) + p1[a]) * 0.5);
        }
        for (const auto& target : targets) {
            eng::Ray r;
            for (int a = 0; a < 3; ++a) {
                r.origin[a] = float(target[a] + 2.0 * extent * unit(rng));
                r.direction[a] = target[a] - r.origin[a];
            }
            r.tmin = 0.0f;
            r.tmax = 3.0f;
            if (std::isfinite(r.direction[0]) && std::isfinite(r.direction[1]) &&
                std::isfinite(r.direction[2]))
                rays.push_back(r);
            // Along one axis onto the vertex: two direction components exactly 0.
            const int axis = int(i % 3);
            eng::Ray axial;
            for (int a = 0; a < 3; ++a) {
                axial.origin[a] = target[a];
                axial.direction[a] = 0.0f;
            }
            axial.origin[axis] = target[axis] - 2.0f * extent;
            axial.direction[axis] = 1.0f;
            axial.tmin = 0.0f;
            axial.tmax = 4.0f * extent;
            if (std::isfinite(axial.origin[axis])) rays.push_back(axial);
        }
    }
    if (back > 0.0f) {
        for (eng::Ray& r : rays) {
            const double len = std::sqrt(double(r.direction[0]) * r.direction[0] +
                                         double(r.direction[1]) * r.direction[1] +
                                         double(r.direction[2]) * r.direction[2]);
            const double steps = back / len;
            for (int a = 0; a < 3; ++a) r.origin[a] = float(r.origin[a] - r.direction[a] * steps);
            r.tmax = float(r.tmax + steps);
        }
    }
    return rays;
}

// Every ray through `scene` both ways, in both modes: the count of hits (to show the rays
// reach the geometry) and the first differences.
size_t expect_same_as_exhaustive(const eng::NvScene& scene, const std::vector<eng::Ray>& rays,
                                 const std::string& what) {
    size_t hits = 0, differ = 0;
    for (const eng::TraversalMode mode : kModes) {
        for (size_t i = 0; i < rays.size(); ++i) {
            const eng::NvHit tree = scene.closest(rays[i], 0, 0xFF, mode);
            const eng::NvHit plain = scene.closest_exhaustive(rays[i], 0, 0xFF, mode);
            hits += plain.hit;
            // Every triangle is opaque: a first-hit query hits exactly when there is a hit.
            if (scene.any(rays[i], 0, 0xFF, mode) != plain.hit && ++differ <= 5)
                ADD_FAILURE() << what << ", " << eng::traversal_mode_name(mode) << ", ray " << i
                              << ": any() differs from " << describe(plain);
            if (same(tree, plain)) continue;
            if (++differ <= 5)
                ADD_FAILURE() << what << ", " << eng::traversal_mode_name(mode) << ", ray " << i
                              << ": traversal " << describe(tree) << ", plain " << describe(plain);
        }
    }
    EXPECT_EQ(differ, 0u) << what << ": of " << 2 * rays.size() << " rays";
    return hits;
}

size_t check_bottom(const ts::TriangleMesh& mesh, uint32_t build_flags, const std::string& what,
                    float back = 0.0f) {
    NvWorld w;
    const auto info = w.blas_info(one_mesh(mesh), build_flags);
    auto obj = w.make_object(info, "blas");
    const auto r = w.build(info, obj);
    EXPECT_TRUE(r.ops[0].executed) << what;
    std::string error;
    auto scene = eng::NvScene::open_bottom(w.memory, obj.address, &error);
    EXPECT_TRUE(scene) << what << ": " << error;
    if (!scene) return 0;
    return expect_same_as_exhaustive(*scene, rays_for(mesh, 3000, 7, back), what);
}

// The tests of this fixture open their scenes under the path it names.
class NvWideTraversalPath : public ::testing::TestWithParam<eng::detail::SimdPath> {
protected:
    void SetUp() override { eng::detail::force_simd_path(GetParam()); }
    void TearDown() override { eng::detail::force_simd_path(std::nullopt); }
};

INSTANTIATE_TEST_SUITE_P(Simd, NvWideTraversalPath,
                         ::testing::Values(eng::detail::SimdPath::kSse,
                                           eng::detail::SimdPath::kAvx2),
                         [](const ::testing::TestParamInfo<eng::detail::SimdPath>& info) {
                             return std::string(info.param == eng::detail::SimdPath::kSse
                                                    ? "Sse4Wide"
                                                    : "Avx2EightWide");
                         });

TEST_P(NvWideTraversalPath, SameHitsAsEveryPrimitiveTestedOnTheBenchMeshes) {
    for (const uint32_t flags :
         {0u, uint32_t(VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV)}) {
        const std::string tree = flags ? "Morton" : "SAH";
        EXPECT_GT(check_bottom(ts::make_icosphere(4, 1.0f), flags, "icosphere " + tree), 1000u);
        EXPECT_GT(check_bottom(ts::make_terrain(40, 40, 1), flags, "terrain " + tree), 1000u);
        EXPECT_GT(check_bottom(ts::make_random_soup(4000, 5, 1.0f, 0.05f), flags, "soup " + tree),
                  1000u);
        EXPECT_GT(check_bottom(ts::make_torus(60, 30, 1.0f, 0.3f), flags, "torus " + tree), 1000u);
    }
}

TEST_P(NvWideTraversalPath, SameHitsAtHugeAndTinyCoordinates) {
    const ts::TriangleMesh sphere = ts::make_icosphere(3, 1.0f);
    EXPECT_GT(check_bottom(scaled(sphere, 1e30f, 0.0f), 0, "sphere at 1e30"), 500u);
    EXPECT_GT(check_bottom(scaled(sphere, 1e-30f, 0.0f), 0, "sphere at 1e-30"), 500u);
    // Triangles of about 1e-3 seen from 4e4 away.
    EXPECT_GT(check_bottom(scaled(sphere, 1e-2f, 0.0f), 0, "1e-2 sphere from 4e4", 4e4f), 500u);
    EXPECT_GT(check_bottom(scaled(sphere, 3e37f, 2e38f), 0, "sphere near FLT_MAX"), 100u);
}

TEST_P(NvWideTraversalPath, SameHitsWithNanAndDegenerateTriangles) {
    ts::TriangleMesh m = ts::make_random_soup(3000, 11, 1.0f, 0.1f);
    const float nan = std::nanf("");
    for (size_t i = 0; i < m.triangles.size(); i += 7) {
        auto& t = m.triangles[i];
        if (i % 3 == 0) m.positions[t[1]] = m.positions[t[0]];  // a point
        if (i % 3 == 1) m.positions[t[2]][1] = nan;             // NaN y: undefined
        if (i % 3 == 2) t[2] = t[1];                            // a segment
    }
    EXPECT_GT(check_bottom(m, 0, "soup with NaN and degenerate triangles"), 1000u);
}

TEST_P(NvWideTraversalPath, SameHitsThroughScaledMirroredAndRotatedInstances) {
    const ts::TriangleMesh sphere = ts::make_icosphere(3, 1.0f);
    const ts::TriangleMesh slab = ts::make_terrain(20, 20, 3);
    std::vector<InstanceSpec> instances;
    auto add = [&](int blas, std::initializer_list<float> m) {
        InstanceSpec s;
        std::copy(m.begin(), m.end(), s.transform);
        s.blas = blas;
        instances.push_back(s);
    };
    add(0, {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0});
    add(0, {1e-2f, 0, 0, 0.5f, 0, 1e-2f, 0, 0.2f, 0, 0, 1e-2f, 0});    // scaled down
    add(0, {-1, 0, 0, 0.3f, 0, 1, 0, 0, 0, 0, 1, 0.1f});               // mirrored
    add(1, {0.6f, -0.8f, 0, 0, 0.8f, 0.6f, 0, 0, 0, 0, 2e3f, -0.5f});  // rotated, stretched
    add(1, {0.6f, -0.8f, 0, 0, 0.8f, 0.6f, 0, 0, 0, 0, 2e3f, -0.5f});  // the same twice: ties
    add(0, {1e4f, 0, 0, 0, 0, -1e4f, 0, 0, 0, 0, 1e4f, 0});            // huge, mirrored
    auto built = build_scene({one_mesh(sphere), one_mesh(slab)}, instances);
    ASSERT_TRUE(built);
    std::string error;
    auto scene = eng::NvScene::open(built->world.memory, built->tlas.address, nullptr, &error);
    ASSERT_TRUE(scene) << error;
    ts::TriangleMesh probe = sphere;  // rays aimed at the first instance's vertices
    for (const auto& p : slab.positions) probe.positions.push_back(p);
    EXPECT_GT(expect_same_as_exhaustive(*scene, rays_for(probe, 4000, 9), "instances"), 1000u);
}

// Object-space origins that are not floats: a mesh around 3000 through an instance scaling it
// by 3, rays starting within a few units of it. The SIMD test rounds the origin to float
// (half an ulp of 3000, 1.2e-4, against distances of about 1): a box test that left that
// rounding out of its widening (the relative part alone) culls grazing hits.
TEST_P(NvWideTraversalPath, SameHitsFromNearbyOriginsThatAreNotFloats) {
    const ts::TriangleMesh sphere = scaled(ts::make_icosphere(3, 1.0f), 1.0f, 3000.0f);
    InstanceSpec in;
    const float transform[12] = {3, 0, 0, 0, 0, 3, 0, 0, 0, 0, 3, 0};
    std::copy(transform, transform + 12, in.transform);
    in.blas = 0;
    auto built = build_scene({one_mesh(sphere)}, {in});
    ASSERT_TRUE(built);
    std::string error;
    auto scene = eng::NvScene::open(built->world.memory, built->tlas.address, nullptr, &error);
    ASSERT_TRUE(scene) << error;
    const ts::TriangleMesh world = scaled(sphere, 3.0f, 0.0f);
    EXPECT_GT(expect_same_as_exhaustive(*scene, rays_for(world, 3000, 13), "origins near 9000"),
              1000u);
}

// The stored tree of a BLAS built from `mesh`, its nodes as the traversal copies them.
std::vector<eng::NvNode> stored_nodes(const ts::TriangleMesh& mesh, uint32_t build_flags) {
    NvWorld w;
    const auto info = w.blas_info(one_mesh(mesh), build_flags);
    auto obj = w.make_object(info, "blas");
    w.build(info, obj);
    const eng::FieldRef where{"blas", -1};
    std::string error;
    const auto header =
        eng::read_nv_header(w.memory.read_bytes(obj.address, sizeof(eng::NvObjectHeader), where),
                            &error);
    EXPECT_TRUE(header) << error;
    if (!header) return {};
    const auto bytes = w.memory.read_bytes(obj.address, header->object_size, where);
    const auto view = eng::open_nv_object(bytes, &error);
    EXPECT_TRUE(view) << error;
    std::vector<eng::NvNode> nodes;
    for (uint32_t i = 0; view && i < view->header.node_count; ++i) nodes.push_back(view->node(i));
    return nodes;
}

// Lanes of `q` whose dequantized box (the traversal's arithmetic) does not contain `f`'s box,
// or whose child or count differs.
int lanes_not_containing(const eng::detail::QuantizedWideNode& q, const eng::detail::WideNode& f) {
    int bad = 0;
    for (int k = 0; k < 4; ++k) {
        if (f.count[k] == eng::detail::kWideEmptyLane) {
            bad += q.count[k] != eng::detail::kQuantizedEmptyLane;
            continue;
        }
        bad += q.count[k] != f.count[k] || q.child[k] != f.child[k];
    }
    for (int a = 0; a < 3; ++a) {
        eng::detail::Float4 lo4, hi4;
        eng::detail::quantized_lanes(q, a, &lo4, &hi4);
        float lo[4], hi[4];
        eng::detail::store4(lo, lo4);
        eng::detail::store4(hi, hi4);
        for (int k = 0; k < 4; ++k)
            if (f.count[k] != eng::detail::kWideEmptyLane)
                bad += !(lo[k] <= f.lo[a][k]) || !(hi[k] >= f.hi[a][k]);
    }
    return bad;
}

TEST(NvWideTraversal, QuantizedBoxesContainTheirFloatBoxes) {
    const ts::TriangleMesh sphere = ts::make_icosphere(3, 1.0f);
    const std::pair<std::string, ts::TriangleMesh> meshes[] = {
        {"icosphere", ts::make_icosphere(4, 1.0f)},
        {"terrain", ts::make_terrain(40, 40, 1)},
        {"soup", ts::make_random_soup(4000, 5, 1.0f, 0.05f)},
        {"sphere at 1e30", scaled(sphere, 1e30f, 0.0f)},
        {"sphere at 1e-30", scaled(sphere, 1e-30f, 0.0f)},
        {"sphere near FLT_MAX", scaled(sphere, 3e37f, 2e38f)},
        {"sphere across the float range", scaled(sphere, 3e38f, 0.0f)},
        {"1e-3 triangles at 4e4", scaled(ts::make_random_soup(2000, 7, 0.25f, 1e-3f), 1.0f, 4e4f)}};
    for (const auto& [what, mesh] : meshes) {
        const std::vector<eng::NvNode> nodes = stored_nodes(mesh, 0);
        const eng::detail::WideTree plain = eng::detail::make_float_wide_tree(nodes);
        const eng::detail::WideTree tree =
            eng::detail::make_wide_tree(nodes, eng::detail::SimdPath::kSse);
        ASSERT_EQ(tree.quantized.size(), plain.nodes.size()) << what << ": not quantized";
        EXPECT_TRUE(tree.nodes.empty()) << what;
        int bad = 0;
        for (size_t i = 0; i < plain.nodes.size(); ++i)
            bad += lanes_not_containing(tree.quantized[i], plain.nodes[i]);
        EXPECT_EQ(bad, 0) << what << ": lanes of " << plain.nodes.size() << " nodes";
    }
}

// The 8-wide nodes hold the stored boxes (each lane the hull of its bounds), children and
// counts of the collapse, and close every unused lane (lo = +inf, hi = -inf); the AVX2 box
// test then reports no unused lane for any ray, axis-parallel ones included.
TEST(NvWideTraversal, EightWideNodesHoldTheStoredBoxesAndCloseUnusedLanes) {
    if (!eng::detail::cpu_has_avx2()) GTEST_SKIP() << "no AVX2 on this CPU";
#if defined(CLASTRACE_AVX2_PATH)
    const ts::TriangleMesh sphere = ts::make_icosphere(3, 1.0f);
    const std::pair<std::string, ts::TriangleMesh> meshes[] = {
        {"icosphere", ts::make_icosphere(4, 1.0f)},
        {"soup", ts::make_random_soup(4000, 5, 1.0f, 0.05f)},
        {"sphere at 1e30", scaled(sphere, 1e30f, 0.0f)},
        {"sphere at 1e-30", scaled(sphere, 1e-30f, 0.0f)},
        {"sphere across the float range", scaled(sphere, 3e38f, 0.0f)},
        {"three triangles", ts::make_random_soup(3, 9, 1.0f, 0.5f)}};
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> coord(-2.0f, 2.0f);
    for (const auto& [what, mesh] : meshes) {
        const std::vector<eng::NvNode> nodes = stored_nodes(mesh, 0);
        const auto plain = eng::detail::make_float_wide_nodes8(nodes);
        const auto tree = eng::detail::make_wide_tree(nodes, eng::detail::SimdPath::kAvx2);
        ASSERT_EQ(tree.nodes8.size(), plain.size()) << what;
        EXPECT_TRUE(tree.quantized.empty() && tree.nodes.empty()) << what;
        int bad = 0, unused_hit = 0;
        for (size_t i = 0; i < plain.size(); ++i) {
            const auto& n = tree.nodes8[i];
            const auto& f = plain[i];
            unsigned used = 0;
            for (int k = 0; k < 8; ++k) {
                const bool empty = f.count[k] == eng::detail::kWideEmptyLane;
                used |= unsigned(!empty) << k;
                bad += n.count[k] != f.count[k] || (!empty && n.child[k] != f.child[k]);
                for (int a = 0; a < 3; ++a)
                    bad += empty ? !(n.lo[a][k] == INFINITY && n.hi[a][k] == -INFINITY)
                                 : !(n.lo[a][k] == std::min(f.lo[a][k], f.hi[a][k]) &&
                                     n.hi[a][k] == std::max(f.lo[a][k], f.hi[a][k]));
            }
            for (int ray = 0; ray < 8; ++ray) {
                const double o[3] = {coord(rng), coord(rng), coord(rng)};
                double d[3] = {coord(rng), coord(rng), coord(rng)};
                if (ray % 2) d[ray % 3] = 0.0;  // an axis-parallel component
                const auto prepared = eng::geometry::prepare_ray(o, d, 0.0, INFINITY);
                const auto wide = eng::detail::make_wide_ray(prepared);
                if (!wide.usable) continue;
                const auto ray8 = eng::detail::make_wide_ray8(wide);
                alignas(32) float entry[8];
                const unsigned hits =
                    ray % 2 ? eng::detail::wide8_hits<true>(ray8, n, INFINITY, entry)
                            : eng::detail::wide8_hits<false>(ray8, n, INFINITY, entry);
                unused_hit += (hits & ~used) != 0;
            }
        }
        EXPECT_EQ(bad, 0) << what << ": lanes of " << plain.size() << " nodes";
        EXPECT_EQ(unused_hit, 0) << what;
    }
#endif
}

// For a ray with no zero direction component and tmin >= 0 the short box test (one multiply
// widening the entry) gives the general test's lanes and entry distances bit for bit, on every
// node, from near and far origins, tmin 0, -0, tiny and large, tmax finite and infinite.
TEST(NvWideTraversal, TheShortEntryWideningGivesTheGeneralEntries) {
    if (!eng::detail::cpu_has_avx2()) GTEST_SKIP() << "no AVX2 on this CPU";
#if defined(CLASTRACE_AVX2_PATH)
    const ts::TriangleMesh sphere = ts::make_icosphere(3, 1.0f);
    const std::pair<std::string, ts::TriangleMesh> meshes[] = {
        {"soup", ts::make_random_soup(4000, 5, 1.0f, 0.05f)},
        {"sphere at 1e20", scaled(sphere, 1e20f, 0.0f)},
        {"sphere at 1e-30", scaled(sphere, 1e-30f, 0.0f)},
        {"1e-3 triangles at 4e4", scaled(ts::make_random_soup(2000, 7, 0.25f, 1e-3f), 1.0f, 4e4f)}};
    const double tmins[] = {0.0, -0.0, 1e-40, 1e-3, 0.5, 3.0};
    const double tmaxes[] = {INFINITY, 2.0, 1e-3};
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> coord(-2.0f, 2.0f);
    for (const auto& [what, mesh] : meshes) {
        const auto tree =
            eng::detail::make_wide_tree(stored_nodes(mesh, 0), eng::detail::SimdPath::kAvx2);
        const ts::Bounds b = ts::bounds_of(mesh);
        const float extent = std::max({b.hi[0] - b.lo[0], b.hi[1] - b.lo[1], b.hi[2] - b.lo[2]});
        int compared = 0, different = 0;
        for (const auto& n : tree.nodes8) {
            for (int ray = 0; ray < 6; ++ray) {
                double o[3], d[3];
                for (int a = 0; a < 3; ++a) {
                    o[a] = (b.lo[a] + b.hi[a]) / 2 + coord(rng) * extent * (ray < 3 ? 1.0f : 1e3f);
                    d[a] = coord(rng);
                }
                if (d[0] == 0.0 || d[1] == 0.0 || d[2] == 0.0) continue;
                for (double tmin : tmins) {
                    const double tmax = tmaxes[(ray + compared) % 3] * (tmin > 1.0 ? 10.0 : 1.0);
                    const auto wide =
                        eng::detail::make_wide_ray(eng::geometry::prepare_ray(o, d, tmin, tmax));
                    if (!wide.usable || !(wide.tmin >= 0.0f)) continue;
                    const auto ray8 = eng::detail::make_wide_ray8(wide);
                    const float tmax_up = eng::detail::float_at_or_above(tmax);
                    alignas(32) float general[8], short_form[8];
                    const unsigned g = eng::detail::wide8_hits<true>(ray8, n, tmax_up, general);
                    const unsigned s = eng::detail::wide8_hits<false>(ray8, n, tmax_up, short_form);
                    different += g != s || std::memcmp(general, short_form, sizeof general) != 0;
                    ++compared;
                }
            }
        }
        EXPECT_GT(compared, 1000) << what;
        EXPECT_EQ(different, 0) << what << " of " << compared;
    }
#endif
}

// The path decides the layout: 8-wide nodes on kAvx2 (where the CPU has it), 4-wide on kSse,
// and the test hook moves the default.
TEST(NvWideTraversal, ThePathPicksTheNodeWidth) {
    const std::vector<eng::NvNode> nodes = stored_nodes(ts::make_icosphere(4, 1.0f), 0);
    const auto sse = eng::detail::make_wide_tree(nodes, eng::detail::SimdPath::kSse);
    EXPECT_FALSE(sse.quantized.empty());
    EXPECT_TRUE(sse.nodes8.empty());
    eng::detail::force_simd_path(eng::detail::SimdPath::kSse);
    EXPECT_EQ(eng::detail::active_simd_path(), eng::detail::SimdPath::kSse);
    EXPECT_TRUE(eng::detail::make_wide_tree(nodes).nodes8.empty());
    eng::detail::force_simd_path(eng::detail::SimdPath::kAvx2);
    const bool avx2 = eng::detail::cpu_has_avx2();
    EXPECT_EQ(eng::detail::active_simd_path(),
              avx2 ? eng::detail::SimdPath::kAvx2 : eng::detail::SimdPath::kSse);
    const auto wide = eng::detail::make_wide_tree(nodes);
    EXPECT_EQ(wide.nodes8.empty(), !avx2);
    // Fewer, wider nodes.
    if (avx2) {
        EXPECT_LT(wide.nodes8.size(), sse.quantized.size());
    }
    eng::detail::force_simd_path(std::nullopt);
}

TEST(NvWideTraversal, TreesWithInfiniteBoxesKeepFloatNodes) {
    eng::NvNode root{};
    for (int a = 0; a < 3; ++a) {
        root.bounds_min[a] = -INFINITY;
        root.bounds_max[a] = INFINITY;
    }
    root.count = 1;
    const eng::detail::WideTree tree =
        eng::detail::make_wide_tree({root}, eng::detail::SimdPath::kSse);
    EXPECT_TRUE(tree.quantized.empty());
    ASSERT_EQ(tree.nodes.size(), 1u);
    EXPECT_EQ(tree.nodes[0].count[0], 1u);
    // The 8-wide nodes are float nodes always.
    if (eng::detail::cpu_has_avx2()) {
        const eng::detail::WideTree tree8 =
            eng::detail::make_wide_tree({root}, eng::detail::SimdPath::kAvx2);
        ASSERT_EQ(tree8.nodes8.size(), 1u);
        EXPECT_EQ(tree8.nodes8[0].count[0], 1u);
        EXPECT_EQ(tree8.nodes8[0].lo[0][0], -INFINITY);
    }
}

// A caterpillar of `levels` inner nodes: inner node L (index 2L) has leaf L (index 2L + 1, record
// L) on the left and inner node L + 1 on the right; the last one has leaf `levels` on its right.
// Along +x from x = -5000 the ray enters each inner box (x from -(2000 - L)) before every leaf
// box (x from 3000 + L): every wide node's inner child is visited first and its leaves wait on
// the stack, which grows by W - 1 entries a level.
std::vector<eng::NvNode> caterpillar(uint32_t levels) {
    std::vector<eng::NvNode> nodes(2 * size_t(levels) + 1);
    auto box = [](eng::NvNode* n, float x0, float x1) {
        n->bounds_min[0] = x0;
        n->bounds_max[0] = x1;
        for (int a = 1; a < 3; ++a) {
            n->bounds_min[a] = -1.0f;
            n->bounds_max[a] = 1.0f;
        }
    };
    for (uint32_t l = 0; l < levels; ++l) {
        eng::NvNode& inner = nodes[2 * l];
        box(&inner, -(2000.0f - float(l)), 4000.0f);
        inner.first = 2 * l + 2;
        inner.count = 0;
        eng::NvNode& leaf = nodes[2 * l + 1];
        box(&leaf, 3000.0f + float(l), 3000.5f + float(l));
        leaf.first = l;
        leaf.count = 1;
    }
    eng::NvNode& last = nodes.back();
    box(&last, 3000.0f + float(levels), 3000.5f + float(levels));
    last.first = levels;
    last.count = 1;
    return nodes;
}

// float_at_or_above steps by the float's bits: the same float as std::nextafter toward +inf
// from the rounded one, through zeros, subnormals, the sign change and both ends of the range.
TEST(NvWideTraversal, FloatAtOrAboveIsTheLeastFloatNotBelow) {
    const double flt_max = std::numeric_limits<float>::max();
    const double least = std::numeric_limits<float>::denorm_min();
    std::vector<double> values = {0.0,
                                  -0.0,
                                  least / 2,
                                  -least / 2,
                                  least * 1.5,
                                  1.0,
                                  1.0 + 1e-12,
                                  -1.0 - 1e-12,
                                  -1.0 + 1e-12,
                                  flt_max,
                                  flt_max * (1 + 1e-12),
                                  -flt_max * (1 + 1e-12),
                                  1e300,
                                  -1e300,
                                  INFINITY,
                                  -INFINITY};
    uint64_t state = 12345;
    for (int k = 0; k < 20000; ++k) {
        state = state * 6364136223846793005ull + 1442695040888963407ull;
        const double x =
            std::ldexp(double(state >> 11) / double(1ull << 53) - 0.5, int(state % 300) - 150);
        values.push_back(x);
    }
    for (const double t : values) {
        float want = float(t);
        if (double(want) < t) want = std::nextafter(want, INFINITY);
        const float got = eng::detail::float_at_or_above(t);
        ASSERT_EQ(std::memcmp(&got, &want, 4), 0) << t;
        ASSERT_GE(double(got), t) << t;
    }
}

bool same_bits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }
bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }
bool same_lanes(eng::detail::Float4 a, eng::detail::Float4 b) {
    alignas(16) float x[4];
    alignas(16) float y[4];
    eng::detail::store4(x, a);
    eng::detail::store4(y, b);
    return std::memcmp(x, y, sizeof x) == 0;
}

// make_plain_object_rays gives the fields each mode reads bit for bit as prepare_ray,
// make_wide_ray and make_triangle4_ray give them, and takes exactly the rays it is meant for:
// float rays, finite, no zero direction component, within both SIMD forms' limits (for
// float32, on 1 / d in double: a float 1 / d that rounds onto 2^±100 is left to the general
// way, which takes it).
TEST(NvWideTraversal, PlainObjectRaysAreTheGeneralOnes) {
    const float specials[] = {0.0f,  -0.0f,     1.0f,      -3.5f,    1e-30f, -1e-38f,  1e-45f,
                              1e30f, -1e30f,    0x1p100f,  0x1p101f, 3e38f,  INFINITY, -INFINITY,
                              NAN,   0x1p-100f, 0x1p-101f, 7e-20f,   2.5e19f};
    uint64_t state = 0x9E3779B97F4A7C15ull;
    auto next = [&state] {
        state = state * 6364136223846793005ull + 1442695040888963407ull;
        return state;
    };
    auto component = [&](bool special) {
        const uint64_t r = next();
        if (special) return specials[(r >> 33) % std::size(specials)];
        return float(std::ldexp(double(r >> 11) / double(1ull << 53) - 0.5, int(r % 80) - 40));
    };
    int plain_count = 0;
    for (int i = 0; i < 200000; ++i) {
        float o[3], d[3];
        for (int a = 0; a < 3; ++a) {
            o[a] = component(next() % 8 == 0);
            d[a] = component(next() % 8 == 0);
        }
        const double tmin = (i % 3 == 0) ? 0.0 : 1e-3;
        const double tmax = (i % 5 == 0) ? INFINITY : 1e4;
        const eng::TraversalMode mode = kModes[i % 2];
        eng::detail::ObjectRays plain;
        const bool taken = eng::detail::make_plain_object_rays(o, d, tmin, tmax, mode, &plain);
        // The general way, from the object-space ray an identity instance gives.
        const double od[3] = {double(o[0]) + 0.0, double(o[1]) + 0.0, double(o[2]) + 0.0};
        const double dd[3] = {d[0], d[1], d[2]};
        const eng::geometry::PreparedRay r = eng::geometry::prepare_ray(od, dd, tmin, tmax, mode);
        const eng::detail::WideRay w = eng::detail::make_wide_ray(r);
        const eng::geometry::Triangle4Ray t = eng::geometry::make_triangle4_ray(r);
        bool meant = w.usable && t.usable;
        for (int a = 0; a < 3; ++a) {
            meant &= std::isfinite(o[a]) && std::isfinite(d[a]) && d[a] != 0;
            meant &= !(std::fabs(1.0 / double(d[a])) > 0x1p100) &&
                     !(std::fabs(1.0 / double(d[a])) < 0x1p-100);
        }
        ASSERT_EQ(taken, meant) << i;
        if (!taken) continue;
        ++plain_count;
        const eng::geometry::PreparedRay& p = plain.exact;
        for (int a = 0; a < 3; ++a) {
            ASSERT_TRUE(same_bits(p.o[a], r.o[a]) && same_bits(p.d[a], r.d[a]) &&
                        same_bits(p.inv[a], r.inv[a]) && same_bits(p.fo[a], r.fo[a]) &&
                        same_bits(p.fd[a], r.fd[a]) && same_bits(p.finv[a], r.finv[a]))
                << i;
            ASSERT_TRUE(same_bits(plain.wide.origin[a], w.origin[a]) &&
                        same_bits(plain.wide.inverse[a], w.inverse[a]) &&
                        plain.wide.zero[a] == w.zero[a])
                << i;
            ASSERT_TRUE(same_lanes(plain.triangles.origin[a], t.origin[a])) << i;
        }
        ASSERT_TRUE(p.kx == r.kx && p.ky == r.ky && p.kz == r.kz && p.mode == r.mode) << i;
        ASSERT_TRUE(same_bits(p.sx, r.sx) && same_bits(p.sy, r.sy) && same_bits(p.sz, r.sz) &&
                    same_bits(p.fsx, r.fsx) && same_bits(p.fsy, r.fsy) && same_bits(p.fsz, r.fsz) &&
                    same_bits(p.tmin, r.tmin) && same_bits(p.tmax, r.tmax))
            << i;
        ASSERT_TRUE(plain.wide.usable && same_bits(plain.wide.widen_down, w.widen_down) &&
                    same_bits(plain.wide.widen_up, w.widen_up) &&
                    same_bits(plain.wide.widen_abs, w.widen_abs) &&
                    same_bits(plain.wide.tmin, w.tmin))
            << i;
        const eng::geometry::Triangle4Ray& pt = plain.triangles;
        ASSERT_TRUE(pt.usable && pt.kx == t.kx && pt.ky == t.ky && pt.kz == t.kz) << i;
        ASSERT_TRUE(same_lanes(pt.sx, t.sx) && same_lanes(pt.sy, t.sy) && same_lanes(pt.sz, t.sz) &&
                    same_lanes(pt.abs_sz, t.abs_sz) && same_lanes(pt.delta2, t.delta2) &&
                    same_lanes(pt.delta4, t.delta4))
            << i;
    }
    // Most rays are plain; the specials reach every refusal.
    EXPECT_GT(plain_count, 50000);
}

// A tree deep enough that the walk's stack spills past its fixed part (WalkStack) still gives
// every leaf the ray meets, each once, on both paths.
TEST(NvWideTraversal, ADeepTreeSpillsTheStackAndLosesNoLeaf) {
    constexpr uint32_t kLevels = 1200;  // 8-wide: 7 leaves pushed a level, 4-wide: 3
    const std::vector<eng::NvNode> nodes = caterpillar(kLevels);
    const double o[3] = {-5000.0, 0.0, 0.0}, d[3] = {1.0, 0.0, 0.0};
    const eng::geometry::PreparedRay rd = eng::geometry::prepare_ray(o, d, 0.0, INFINITY);
    const eng::detail::WideRay wr = eng::detail::make_wide_ray(rd);
    ASSERT_TRUE(wr.usable);
    for (const auto path : {eng::detail::SimdPath::kSse, eng::detail::SimdPath::kAvx2}) {
        const eng::detail::WideTree tree = eng::detail::make_wide_tree(nodes, path);
        ASSERT_GT(tree.node_count(), 0u);
        std::vector<int> seen(kLevels + 1, 0);
        double tmax = INFINITY;
        eng::detail::walk_wide(
            tree, wr, &tmax,
            [&](uint32_t first, uint32_t count) {
                for (uint32_t k = first; k < first + count && k < seen.size(); ++k) ++seen[k];
                return false;
            },
            [](uint32_t, uint32_t) {});
        for (uint32_t k = 0; k <= kLevels; ++k)
            ASSERT_EQ(seen[k], 1) << "record " << k << ", path " << int(path);
    }
}

// The wide walk's stack (BurstStack) against a plain vector: random bursts of pushes (room
// made once per burst, some written in place and grown) and pops through a fixed part of 16,
// so that the older half spills to the vector and comes back many times; every pop must give
// what the vector gives, in order.
TEST(NvWideTraversal, TheBurstStackPopsWhatAVectorPops) {
    using Stack = eng::BurstStack<uint32_t, 16, 8>;
    uint32_t entries[Stack::kSize];
    std::vector<uint32_t> overflow, model;
    Stack stack(entries, &overflow);
    std::mt19937 rng(7);
    uint32_t next = 0;
    size_t spilled_at_most = 0;
    for (int step = 0; step < 20000; ++step) {
        if (rng() % 2 == 0) {
            stack.make_room();
            const uint32_t burst = 1 + rng() % 8;
            if (rng() % 2 == 0) {
                for (uint32_t k = 0; k < burst; ++k) stack.push(next++);
            } else {
                for (uint32_t k = 0; k < burst; ++k) stack.top()[k] = next++;
                stack.grow(burst);
            }
            for (uint32_t k = burst; k > 0; --k) model.push_back(next - k);
        } else {
            const uint32_t pops = 1 + rng() % 8;
            for (uint32_t k = 0; k < pops; ++k) {
                uint32_t e = 0;
                const bool popped = stack.pop(&e);
                ASSERT_EQ(popped, !model.empty()) << "step " << step;
                if (!popped) break;
                ASSERT_EQ(e, model.back()) << "step " << step;
                model.pop_back();
            }
        }
        spilled_at_most = std::max(spilled_at_most, overflow.size());
    }
    EXPECT_GE(spilled_at_most, 64u);  // the spill and refill paths ran, several halves deep
    uint32_t e = 0;
    while (!model.empty()) {
        ASSERT_TRUE(stack.pop(&e));
        ASSERT_EQ(e, model.back());
        model.pop_back();
    }
    EXPECT_FALSE(stack.pop(&e));
}

}  // namespace
}  // namespace clastrace::nvtest
