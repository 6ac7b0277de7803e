// SPDX-License-Identifier: Apache-2.0
// vkCmdBuildAccelerationStructureNV semantics: sizes, every vertex format / index type /
// stride / transform NV allows, the access list the hazard checker reads, and every rule
// the command and the structs it names put on memory contents and object state.
#include "nv_scene.h"

#include <clastrace/engine/vertex_format.h>
#include <clastrace/testsupport/rays.h>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <random>

namespace clastrace::nvtest {
namespace {

bool has(const eng::ExecutionRecord& r, const std::string& rule) {
    for (const auto& f : r.findings)
        if (f.rule == rule) return true;
    return false;
}
std::string rules(const eng::ExecutionRecord& r) {
    std::string s;
    for (const auto& f : r.findings) s += f.rule + " (" + f.message + ")\n";
    return s;
}

TEST(NvBuild, BottomLevelSizeWithinRequirementAndHeaderCounts) {
    NvWorld w;
    BlasSpec spec;
    spec.geometries.push_back({ts::make_icosphere(3, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    spec.geometries.push_back({ts::make_torus(8, 6, 2.0f, 0.2f), {}, 0});
    const auto info = w.blas_info(spec);
    auto obj = w.make_object(info, "blas");
    const auto r = w.build(info, obj);
    ASSERT_TRUE(r.ops[0].executed) << rules(r);
    EXPECT_TRUE(r.findings.empty()) << rules(r);
    const size_t tris =
        spec.geometries[0].mesh.triangles.size() + spec.geometries[1].mesh.triangles.size();
    EXPECT_LE(r.ops[0].dst_size, eng::nv_memory_requirements(info).object);
    EXPECT_GE(r.ops[0].dst_size, 96 + 2 * 32 + tris * 48);
    std::string error;
    auto view =
        eng::open_nv_object(w.memory.read_bytes(obj.address, r.ops[0].dst_size, {}), &error);
    ASSERT_TRUE(view) << error;
    EXPECT_EQ(view->header.primitive_count, tris);
    EXPECT_EQ(view->header.geometry_count, 2u);
    EXPECT_EQ(view->header.kind, uint8_t(eng::NvObjectKind::kBottomLevel));
    EXPECT_FLOAT_EQ(view->header.bounds_max[0], 2.2f);
}

// The bytes of one mesh's bottom level built alone, with `flags`.
std::vector<std::byte> built_bytes(const ts::TriangleMesh& mesh,
                                   VkBuildAccelerationStructureFlagsNV flags) {
    NvWorld w;
    BlasSpec spec;
    spec.geometries.push_back({mesh, {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    const auto info = w.blas_info(spec, flags);
    auto obj = w.make_object(info, "blas");
    const auto r = w.build(info, obj);
    EXPECT_TRUE(r.ops[0].executed) << rules(r);
    const auto span = w.memory.read_bytes(obj.address, r.ops[0].dst_size, {});
    return std::vector<std::byte>(span.begin(), span.end());
}

// Both builders (SAH by default, Morton for PREFER_FAST_BUILD) write the same bytes at 1
// and at 2 threads on a mesh large enough to build its top levels on TBB tasks, and build
// different trees (the flag reaches the builder).
TEST(NvBuild, BytesDoNotDependOnThreadCountForEitherBuilder) {
    const ts::TriangleMesh mesh = ts::make_random_soup(40000, 17, 1.0f, 0.05f);
    auto bytes_at = [&](int threads, VkBuildAccelerationStructureFlagsNV flags) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(threads));
        return built_bytes(mesh, flags);
    };
    const auto fast = VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV;
    const auto sah1 = bytes_at(1, 0), sah2 = bytes_at(2, 0), morton1 = bytes_at(1, fast),
               morton2 = bytes_at(2, fast);
    EXPECT_EQ(sah1, sah2);
    EXPECT_EQ(morton1, morton2);
    ASSERT_EQ(sah1.size() > 0, true);
    std::string error;
    auto a = eng::open_nv_object(sah1, &error), b = eng::open_nv_object(morton1, &error);
    ASSERT_TRUE(a && b) << error;
    EXPECT_EQ(a->header.primitive_count, 40000u);
    EXPECT_EQ(b->header.primitive_count, 40000u);
    bool same_tree = a->header.node_count == b->header.node_count;
    for (uint32_t i = 0; same_tree && i < a->header.node_count; ++i) {
        const eng::NvNode x = a->node(i), y = b->node(i);
        same_tree = std::memcmp(&x, &y, sizeof x) == 0;
    }
    EXPECT_FALSE(same_tree);
}

// A thread keeps the gather's and the tree's arrays between builds (nv_internal.h): what a
// build leaves in them must not reach the next one. A mesh built again after a larger one
// with inactive triangles (NaN holes: the record lookup through the active ones) and after a
// smaller one gives the same bytes as its first build, with either builder.
TEST(NvBuild, KeptArraysCarryNothingBetweenBuilds) {
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    ts::TriangleMesh holes = ts::make_terrain(220, 220, 4);
    for (size_t i = 0; i < holes.positions.size(); i += 5) holes.positions[i][0] = NAN;
    const ts::TriangleMesh mesh = ts::make_torus(120, 60, 1.0f, 0.3f),
                           small = ts::make_icosphere(2, 1.0f);
    for (VkBuildAccelerationStructureFlagsNV flags :
         {VkBuildAccelerationStructureFlagsNV(0),
          VkBuildAccelerationStructureFlagsNV(
              VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV)}) {
        const auto first = built_bytes(mesh, flags);
        const auto with_holes = built_bytes(holes, flags);
        EXPECT_LT(eng::open_nv_object(with_holes, nullptr)->header.primitive_count,
                  holes.triangles.size());
        EXPECT_EQ(built_bytes(mesh, flags), first) << "after the larger mesh, flags " << flags;
        (void)built_bytes(small, flags);
        EXPECT_EQ(built_bytes(mesh, flags), first) << "after the smaller mesh, flags " << flags;
        EXPECT_EQ(built_bytes(holes, flags), with_holes) << "flags " << flags;
    }
}

// The same surface in every encoding NV allows must give bit-identical answers to the
// decoded float positions in R32G32B32 / UINT32 / packed form.
uint16_t to_half(float f) {  // exact for the values used (multiples of 1/64 in [-1, 1])
    if (f == 0.0f) return std::signbit(f) ? 0x8000 : 0;
    uint32_t bits;
    std::memcpy(&bits, &f, 4);
    const uint32_t sign = (bits >> 16) & 0x8000, exp = ((bits >> 23) & 0xFF) - 127 + 15,
                   mant = (bits >> 13) & 0x3FF;
    return uint16_t(sign | (exp << 10) | mant);
}

// A wavy grid with coordinates exact in half (k/64) and SNORM16 (k/32767) forms: its vertex
// positions and its triangles' corners (two triangles a cell).
struct WavyGrid {
    std::vector<std::array<float, 3>> positions;
    std::vector<uint32_t> corners;
};

WavyGrid wavy_grid() {
    const int n = 10;
    std::mt19937 rng(5);
    WavyGrid grid;
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x)
            grid.positions.push_back(
                {(x - n / 2) / 8.0f, (y - n / 2) / 8.0f, float(int(rng() % 17) - 8) / 64.0f});
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            const uint32_t a = y * (n + 1) + x, b = a + 1, c = a + n + 1, d = c + 1;
            grid.corners.insert(grid.corners.end(), {a, b, d, a, d, c});
        }
    return grid;
}

// One vertex format NV allows: its component count and kind.
struct VertexEncoding {
    VkFormat format = VK_FORMAT_UNDEFINED;
    uint32_t components = 3;
    bool snorm = false, half = false;
    uint32_t component_bytes() const { return (snorm || half) ? 2 : 4; }
};

VertexEncoding encoding_of(VkFormat f) {
    VertexEncoding e;
    e.format = f;
    e.components = (f == VK_FORMAT_R32G32_SFLOAT || f == VK_FORMAT_R16G16_SFLOAT ||
                    f == VK_FORMAT_R16G16_SNORM)
                       ? 2
                       : 3;
    e.snorm = f == VK_FORMAT_R16G16_SNORM || f == VK_FORMAT_R16G16B16_SNORM;
    e.half = f == VK_FORMAT_R16G16B16_SFLOAT || f == VK_FORMAT_R16G16_SFLOAT;
    return e;
}

// The grid's vertices in one encoding (one vertex per corner for NONE_NV), `pad` bytes after
// each, and the decoded reference positions (the values the GPU sees).
struct EncodedVertices {
    std::vector<uint8_t> bytes;
    std::vector<std::array<float, 3>> decoded;
    uint32_t stride = 0;
    size_t count = 0;
};

// Writes component `x` at `dst` in encoding `e`; returns the value the GPU decodes.
float encode_component(const VertexEncoding& e, float x, uint8_t* dst) {
    if (e.snorm) {
        const int16_t q = int16_t(std::lround(x * 32767.0f));
        std::memcpy(dst, &q, 2);
        return std::max(float(q) / 32767.0f, -1.0f);
    }
    if (e.half) {
        const uint16_t h = to_half(x);
        std::memcpy(dst, &h, 2);
    } else {
        std::memcpy(dst, &x, 4);
    }
    return x;
}

EncodedVertices encode_vertices(const WavyGrid& grid, const VertexEncoding& e, VkIndexType it,
                                uint32_t pad) {
    EncodedVertices v;
    v.stride = e.components * e.component_bytes() + pad;  // pad keeps the component alignment
    v.count = it == VK_INDEX_TYPE_NONE_NV ? grid.corners.size() : grid.positions.size();
    v.bytes.resize(v.count * v.stride);
    v.decoded.resize(v.count);
    for (size_t k = 0; k < v.count; ++k) {
        const auto& p = grid.positions[it == VK_INDEX_TYPE_NONE_NV ? grid.corners[k] : k];
        for (uint32_t c = 0; c < 3; ++c)
            v.decoded[k][c] =
                c < e.components
                    ? encode_component(e, p[c],
                                       v.bytes.data() + k * v.stride + c * e.component_bytes())
                    : 0.0f;
    }
    return v;
}

std::vector<uint8_t> index_bytes(const std::vector<uint32_t>& corners, VkIndexType it) {
    std::vector<uint8_t> ib(corners.size() * (it == VK_INDEX_TYPE_UINT16 ? 2 : 4));
    for (size_t k = 0; k < corners.size(); ++k) {
        if (it == VK_INDEX_TYPE_UINT16) {
            const uint16_t s = uint16_t(corners[k]);
            std::memcpy(ib.data() + 2 * k, &s, 2);
        } else {
            std::memcpy(ib.data() + 4 * k, &corners[k], 4);
        }
    }
    return ib;
}

const float kGridTransform[12] = {0.5f, 0.25f, 0, 1.0f, -0.25f, 0.5f, 0, -2.0f, 0, 0, 2.0f, 0.5f};

// The geometry of the encoded vertices, its indices and (with_transform) kGridTransform, put
// into w's memory.
eng::NvGeometry encoded_geometry(NvWorld& w, const WavyGrid& grid, const EncodedVertices& v,
                                 VkFormat f, VkIndexType it, bool with_transform) {
    eng::NvGeometry g;
    g.flags = VK_GEOMETRY_OPAQUE_BIT_NV;
    g.triangles.vertex_address = w.put(v.bytes.data(), v.bytes.size(), "vb");
    g.triangles.vertex_count = uint32_t(v.count);
    g.triangles.vertex_format = f;
    g.triangles.vertex_stride = v.stride;
    g.triangles.index_type = it;
    if (it != VK_INDEX_TYPE_NONE_NV) {
        const std::vector<uint8_t> ib = index_bytes(grid.corners, it);
        g.triangles.index_address = w.put(ib.data(), ib.size(), "ib");
        g.triangles.index_count = uint32_t(grid.corners.size());
    }
    if (with_transform) g.triangles.transform_address = w.put(kGridTransform, 48, "transform");
    return g;
}

// Reference: the decoded (and transformed, in float as the GPU does) positions as a float mesh.
GeometrySpec reference_geometry(const WavyGrid& grid, const EncodedVertices& v, VkIndexType it,
                                bool with_transform) {
    GeometrySpec gs;
    for (auto p : v.decoded) {
        if (with_transform) {
            const float x = p[0], y = p[1], z = p[2];
            const float* m = kGridTransform;
            for (int row = 0; row < 3; ++row)
                p[row] = m[4 * row] * x + m[4 * row + 1] * y + m[4 * row + 2] * z + m[4 * row + 3];
        }
        gs.mesh.positions.push_back({p[0], p[1], p[2]});
    }
    const std::vector<uint32_t>& order = grid.corners;
    for (size_t k = 0; k + 2 < order.size(); k += 3) {
        if (it == VK_INDEX_TYPE_NONE_NV)
            gs.mesh.triangles.push_back({uint32_t(k), uint32_t(k + 1), uint32_t(k + 2)});
        else
            gs.mesh.triangles.push_back({order[k], order[k + 1], order[k + 2]});
    }
    return gs;
}

// Every ray hits the two bottom levels alike; *hits counts the rays that hit.
void expect_same_hits(const NvWorld& w, uint64_t built, uint64_t reference,
                      const std::vector<ts::TestRay>& rays, VkFormat f, VkIndexType it,
                      size_t* hits) {
    auto a = eng::NvScene::open_bottom(w.memory, built, nullptr);
    auto b = eng::NvScene::open_bottom(w.memory, reference, nullptr);
    ASSERT_TRUE(a && b);
    for (const auto& tr : rays) {
        const eng::Ray ray{{tr.origin[0], tr.origin[1], tr.origin[2]},
                           0.0f,
                           {tr.direction[0], tr.direction[1], tr.direction[2]},
                           tr.tmax};
        const eng::NvHit ha = a->closest(ray, 0, 0xFF), hb = b->closest(ray, 0, 0xFF);
        ASSERT_EQ(ha.hit, hb.hit) << "format " << f << " index type " << it;
        if (!ha.hit) continue;
        ++*hits;
        ASSERT_EQ(ha.t, hb.t) << "format " << f << " index type " << it;
        ASSERT_EQ(ha.primitive_index, hb.primitive_index);
        ASSERT_EQ(ha.hit_kind, hb.hit_kind);
    }
}

// One combination: the grid built in that encoding answers every ray as its float reference.
void check_encoding(const WavyGrid& grid, const std::vector<ts::TestRay>& rays, VkFormat f,
                    VkIndexType it, uint32_t pad, bool with_transform) {
    NvWorld w;
    const EncodedVertices v = encode_vertices(grid, encoding_of(f), it, pad);
    eng::NvObjectInfo info;
    info.geometries.push_back(encoded_geometry(w, grid, v, f, it, with_transform));
    auto obj = w.make_object(info, "blas");
    const auto r = w.build(info, obj);
    ASSERT_TRUE(r.ops[0].executed) << rules(r);
    ASSERT_TRUE(r.findings.empty()) << rules(r);
    BlasSpec spec;
    spec.geometries.push_back(reference_geometry(grid, v, it, with_transform));
    auto ref_info = w.blas_info(spec);
    auto ref_obj = w.make_object(ref_info, "ref");
    ASSERT_TRUE(w.build(ref_info, ref_obj).ops[0].executed);
    size_t hits = 0;
    ASSERT_NO_FATAL_FAILURE(expect_same_hits(w, obj.address, ref_obj.address, rays, f, it, &hits));
    EXPECT_GT(hits, 40u) << "format " << f;
}

TEST(NvBuild, EveryVertexFormatIndexTypeStrideAndTransformMatchesFloatReference) {
    const WavyGrid grid = wavy_grid();
    const VkFormat formats[] = {VK_FORMAT_R32G32B32_SFLOAT, VK_FORMAT_R32G32_SFLOAT,
                                VK_FORMAT_R16G16B16_SFLOAT, VK_FORMAT_R16G16_SFLOAT,
                                VK_FORMAT_R16G16_SNORM,     VK_FORMAT_R16G16B16_SNORM};
    const VkIndexType index_types[] = {VK_INDEX_TYPE_UINT16, VK_INDEX_TYPE_UINT32,
                                       VK_INDEX_TYPE_NONE_NV};
    ts::Bounds box;
    box.extend({-1.5f, -3.5f, -1.5f});
    box.extend({2.5f, 1.5f, 1.5f});
    const auto rays = ts::random_rays(box, 3000, 8);
    int combos = 0;
    for (VkFormat f : formats)
        for (VkIndexType it : index_types)
            for (uint32_t pad : {0u, 10u})
                for (bool with_transform : {false, true}) {
                    ASSERT_NO_FATAL_FAILURE(check_encoding(grid, rays, f, it, pad, with_transform));
                    ++combos;
                }
    EXPECT_EQ(combos, 6 * 3 * 2 * 2);
}

TEST(NvBuild, AccessesNameEveryRangeWithStageAndAccess) {
    std::vector<BlasSpec> blas(1);
    blas[0].geometries.push_back({ts::make_icosphere(1, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    std::vector<InstanceSpec> inst(3);
    inst[1].transform[3] = 5;
    inst[2].blas = -1;
    auto s = build_scene(blas, inst);
    ASSERT_TRUE(s->findings.empty()) << s->findings.front();
    // Rebuild the TLAS and look at its record.
    eng::NvObjectInfo top = *s->tlas.created;
    const auto r = s->world.build(top, s->tlas, s->instance_address);
    ASSERT_TRUE(r.ops[0].executed);
    bool saw_instances = false, saw_blas = false, saw_scratch = false, saw_dst = false;
    for (const auto& a : r.accesses) {
        EXPECT_EQ(a.stage, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR);
        if (a.field == "instanceData") {
            saw_instances = true;
            EXPECT_EQ(a.begin, s->instance_address);
            EXPECT_EQ(a.end - a.begin, 3u * 64);
            EXPECT_FALSE(a.is_write);
            EXPECT_EQ(a.access, VK_ACCESS_2_SHADER_READ_BIT);
        } else if (a.field.find("accelerationStructureReference") != std::string::npos) {
            saw_blas = true;
            EXPECT_EQ(a.begin, s->blas[0].address);
            EXPECT_EQ(a.access, VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
        } else if (a.field == "scratch") {
            saw_scratch = true;
            EXPECT_TRUE(a.is_write);
        } else if (a.field == "dst") {
            saw_dst = true;
            EXPECT_EQ(a.begin, s->tlas.address);
            EXPECT_EQ(a.access, VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
        }
    }
    EXPECT_TRUE(saw_instances && saw_blas && saw_scratch && saw_dst);
    // One BLAS referenced twice is read once.
    size_t blas_reads = 0;
    for (const auto& a : r.accesses)
        blas_reads += a.field.find("accelerationStructureReference") != std::string::npos;
    EXPECT_EQ(blas_reads, 1u);
}

TEST(NvBuild, InactiveAndMaskedInstancesAndEmptyTopLevel) {
    std::vector<BlasSpec> blas(1);
    blas[0].geometries.push_back({ts::make_icosphere(1, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    const eng::Ray down{{0, 0, 10}, 0, {0, 0, -1}, 100};
    {
        auto s = build_scene(blas, {});
        ASSERT_TRUE(s->findings.empty());
        auto scene = eng::NvScene::open(s->world.memory, s->tlas.address, nullptr, nullptr);
        ASSERT_TRUE(scene);
        EXPECT_EQ(scene->instance_count(), 0u);
        EXPECT_FALSE(scene->closest(down, 0, 0xFF).hit);
        EXPECT_FALSE(scene->any(down, 0, 0xFF));
    }
    std::vector<InstanceSpec> inst(3);
    inst[0].blas = -1;  // reference 0: inactive
    inst[1].mask = 0x0F;
    inst[1].transform[11] = 3;  // z + 3: the top one
    inst[2].custom_index = 0xABCDEF;
    inst[2].sbt_offset = 77;
    auto s = build_scene(blas, inst);
    ASSERT_TRUE(s->findings.empty());
    auto scene = eng::NvScene::open(s->world.memory, s->tlas.address, nullptr, nullptr);
    ASSERT_TRUE(scene);
    const eng::NvHit h1 = scene->closest(down, 0, 0x01);
    ASSERT_TRUE(h1.hit);
    EXPECT_EQ(h1.instance_index, 1u);
    EXPECT_NEAR(h1.t, 6.0f, 0.1f);
    const eng::NvHit h2 = scene->closest(down, 0, 0xF0);  // instance 1 masked out
    ASSERT_TRUE(h2.hit);
    EXPECT_EQ(h2.instance_index, 2u);
    EXPECT_EQ(h2.instance_custom_index, 0xABCDEFu);
    EXPECT_EQ(h2.sbt_offset, 77u);
    EXPECT_EQ(h2.hit_kind, eng::kHitKindFrontFacing);
    EXPECT_FALSE(scene->closest(down, 0, 0x00).hit);
    // Inside the sphere looking out: back faces; culled unless the instance disables culling.
    const eng::Ray out{{0, 0, 0}, 0, {0, 0, -1}, 100};
    const eng::NvHit back = scene->closest(out, 0, 0xF0);
    ASSERT_TRUE(back.hit);
    EXPECT_EQ(back.hit_kind, eng::kHitKindBackFacing);
    EXPECT_FALSE(scene->closest(out, eng::kRayFlagCullBackFacingTriangles, 0xF0).hit);
}

// Each rule: a good command, one change, the rule expected (and the build refused where
// the spec leaves nothing defined).
struct RuleCase {
    const char* rule;
    std::function<void(eng::NvBuildCommand&, NvWorld&, eng::NvBuildOptions&)> change;
    bool builds;
};

// A clean bottom-level build of an icosphere that allows updates, with the scratch it needs.
eng::NvBuildCommand clean_bottom_level_build(NvWorld& w) {
    BlasSpec spec;
    spec.geometries.push_back({ts::make_icosphere(1, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    eng::NvBuildCommand cmd;
    cmd.info = w.blas_info(spec, VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_NV);
    cmd.dst = w.make_object(cmd.info, "dst");
    const auto need = eng::nv_memory_requirements(cmd.info);
    cmd.scratch_address = w.scratch(need.build_scratch);
    cmd.scratch_available = need.build_scratch;
    return cmd;
}

eng::NvTriangles& triangles_of(eng::NvBuildCommand& c) { return c.info.geometries[0].triangles; }

// The rules on the command, its objects and its info.
std::vector<RuleCase> command_rule_cases() {
    return {
        {eng::kVuidNvUpdateNoSrc, [](auto& c, auto&, auto&) { c.update = true; }, false},
        {eng::kVuidNvUpdateNotAllowed,
         [](auto& c, auto& w, auto&) {
             c.update = true;
             c.src = w.make_object(c.info, "src");
             c.src.built = true;
             c.src.built_flags = 0;
         },
         false},
        {eng::kVuidNvBuildScratch, [](auto& c, auto&, auto&) { c.scratch_available = 64; }, true},
        {eng::kVuidNvScratchUsage,
         [](auto& c, auto&, auto&) { c.scratch_ray_tracing_usage = false; }, true},
        {eng::kVuidNvDstBound, [](auto& c, auto&, auto&) { c.dst.bound = false; }, false},
        {eng::kVuidNvDstCompatible,
         [](auto& c, auto&, auto&) { c.dst.created->geometries[0].triangles.index_count = 3; },
         false},
        {eng::kVuidNvDstCompatible, [](auto& c, auto&, auto&) { c.dst.created->flags = 0; }, false},
        {eng::kVuidNvGeometryCount, [](auto&, auto&, auto& o) { o.limits.max_geometry_count = 0; },
         false},
        {eng::kVuidInfoTriangleCount,
         [](auto&, auto&, auto& o) { o.limits.max_triangle_count = 10; }, false},
        {eng::kVuidInfoBottomInstances, [](auto& c, auto&, auto&) { c.info.instance_count = 1; },
         false},
        {eng::kVuidInfoFastBoth,
         [](auto& c, auto&, auto&) {
             c.info.flags |= VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_NV |
                             VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV;
             c.dst.created->flags = c.info.flags;
         },
         true},
        {eng::kVuidInfoMixedTypes,
         [](auto& c, auto&, auto&) {
             eng::NvGeometry g;
             g.type = VK_GEOMETRY_TYPE_AABBS_NV;
             c.info.geometries.push_back(g);
             c.dst.created->geometries.push_back(g);
         },
         false},
    };
}

// The rules on the geometry's memory and contents.
std::vector<RuleCase> geometry_rule_cases() {
    return {
        {eng::kVuidVertexFormat,
         [](auto& c, auto&, auto&) { triangles_of(c).vertex_format = VK_FORMAT_R8G8B8A8_UNORM; },
         true},
        {eng::kVuidVertexOffset,
         [](auto& c, auto&, auto&) { triangles_of(c).vertex_available = 0; }, true},
        {eng::kVuidVertexOffsetAlign,
         [](auto& c, auto&, auto&) { triangles_of(c).vertex_offset = 2; }, true},
        {eng::kVuidIndexType,
         [](auto& c, auto&, auto&) { triangles_of(c).index_type = VK_INDEX_TYPE_UINT8_EXT; }, true},
        {eng::kVuidIndexOffset, [](auto& c, auto&, auto&) { triangles_of(c).index_available = 0; },
         true},
        {eng::kVuidIndexOffsetAlign,
         [](auto& c, auto&, auto&) { triangles_of(c).index_offset = 2; }, true},
        {eng::kVuidIndexNoneData,
         [](auto& c, auto&, auto&) {
             triangles_of(c).index_type = VK_INDEX_TYPE_NONE_NV;
             triangles_of(c).index_count = 0;
         },
         true},
        {eng::kVuidIndexNoneCount,
         [](auto& c, auto&, auto&) {
             triangles_of(c).index_type = VK_INDEX_TYPE_NONE_NV;
             triangles_of(c).index_address = 0;
         },
         true},
        {eng::kRuleNvPartialTriangle,
         [](auto& c, auto&, auto&) { triangles_of(c).index_count -= 1; }, true},
        {eng::kVuidTransformOffset,
         [](auto& c, auto& w, auto&) {
             const float m[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
             triangles_of(c).transform_address = w.put(m, 48, "t");
             triangles_of(c).transform_available = 0;
         },
         true},
        {eng::kVuidTransformOffsetAlign,
         [](auto& c, auto& w, auto&) {
             const float m[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
             triangles_of(c).transform_address = w.put(m, 48, "t");
             triangles_of(c).transform_offset = 8;
         },
         true},
        {eng::kRuleNvMemoryFault,
         [](auto& c, auto&, auto&) { triangles_of(c).vertex_address = 0x10; }, false},
        {eng::kRuleNvMemoryFault,
         [](auto& c, auto&, auto&) { triangles_of(c).vertex_stride = 1ull << 62; }, false},
        {eng::kRuleNvObjectTooLarge, [](auto& c, auto&, auto&) { c.dst.size = 200; }, false},
        {eng::kRuleNvScratchOverlap,
         [](auto& c, auto&, auto&) {
             c.scratch_address = c.info.geometries[0].triangles.vertex_address;
         },
         true},
        {eng::kRuleNvIndexOutOfRange,
         [](auto& c, auto&, auto&) { triangles_of(c).vertex_count = 3; }, true},
    };
}

// The unchanged command is clean; case i's change makes its rule fire.
void expect_rule_fires(const RuleCase& rule_case, size_t i) {
    {
        NvWorld w0;
        eng::NvBuildCommand c0 = clean_bottom_level_build(w0);
        const auto r0 = eng::execute_nv_build(c0, w0.memory);
        ASSERT_TRUE(r0.findings.empty()) << rules(r0);
    }
    NvWorld w;
    eng::NvBuildCommand cmd = clean_bottom_level_build(w);
    eng::NvBuildOptions options;
    rule_case.change(cmd, w, options);
    const auto r = eng::execute_nv_build(cmd, w.memory, options);
    EXPECT_TRUE(has(r, rule_case.rule))
        << "case " << i << " expected " << rule_case.rule << ", got:\n"
        << rules(r);
    EXPECT_EQ(r.ops[0].executed, rule_case.builds) << "case " << i << " " << rule_case.rule << "\n"
                                                   << rules(r);
    for (const auto& f : r.findings) EXPECT_FALSE(f.message.empty());
}

TEST(NvBuild, EveryRuleFiresOnItsInput) {
    std::vector<RuleCase> cases = command_rule_cases();
    for (RuleCase& c : geometry_rule_cases()) cases.push_back(std::move(c));
    for (size_t i = 0; i < cases.size(); ++i)
        ASSERT_NO_FATAL_FAILURE(expect_rule_fires(cases[i], i));
}

TEST(NvBuild, TopLevelRulesOnInstanceReferences) {
    std::vector<BlasSpec> blas(1);
    blas[0].geometries.push_back({ts::make_icosphere(1, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    std::vector<InstanceSpec> inst(2);
    auto s = build_scene(blas, inst);
    NvWorld& w = s->world;
    eng::NvObjectInfo top = *s->tlas.created;
    // A handle that names nothing -> 12264; an address with no object -> not built; the TLAS handle itself -> 12264.
    for (uint64_t bad : {uint64_t(0xDEAD0000), s->instance_address, s->tlas.handle}) {
        std::vector<uint8_t> bytes = w.instance_bytes(inst, {bad});
        const uint64_t ia = w.put(bytes.data(), bytes.size(), "instances");
        eng::NvObjectBinding dst = w.make_object(top, "tlas2");
        eng::NvBuildOptions o;
        const uint64_t tlas_handle = s->tlas.handle;
        o.resolve_reference = [&](uint64_t h) -> std::optional<uint64_t> {
            if (h == 0xDEAD0000) return std::nullopt;
            return h;
        };
        const auto r = w.build(top, dst, ia, false, nullptr, o);
        ASSERT_TRUE(r.ops[0].executed) << rules(r);
        const char* expected = bad == 0xDEAD0000 || bad == tlas_handle ? eng::kVuidNvReference
                                                                       : eng::kRuleNvBlasNotBuilt;
        EXPECT_TRUE(has(r, expected)) << rules(r);
        auto scene = eng::NvScene::open(w.memory, dst.address, nullptr, nullptr);
        ASSERT_TRUE(scene);
        EXPECT_EQ(scene->instances_reached(), 0u);
        EXPECT_FALSE(scene->closest(eng::Ray{{0, 0, 5}, 0, {0, 0, -1}, 100}, 0, 0xFF).hit);
    }
    // instanceData usage and a NULL instanceData with instances.
    {
        eng::NvBuildCommand cmd;
        cmd.info = top;
        cmd.dst = w.make_object(top, "tlas3");
        cmd.scratch_address = w.scratch(4096);
        cmd.scratch_available = 4096;
        cmd.instance_address = s->instance_address;
        cmd.instance_buffer_ray_tracing_usage = false;
        auto r = eng::execute_nv_build(cmd, w.memory);
        EXPECT_TRUE(has(r, eng::kVuidNvInstanceUsage)) << rules(r);
        cmd.instance_address = 0;
        r = eng::execute_nv_build(cmd, w.memory);
        EXPECT_TRUE(has(r, eng::kRuleNvMemoryFault)) << rules(r);
        EXPECT_FALSE(r.ops[0].executed);
        cmd.info.geometries.push_back({});
        cmd.dst.created->geometries.push_back({});
        r = eng::execute_nv_build(cmd, w.memory);
        EXPECT_TRUE(has(r, eng::kVuidInfoTopGeometries)) << rules(r);
    }
}

}  // namespace
}  // namespace clastrace::nvtest
