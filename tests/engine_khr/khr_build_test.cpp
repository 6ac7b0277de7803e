// SPDX-License-Identifier: Apache-2.0
// execute_khr_build's record and rules: the accesses it names (Vulkan field names), the build
// sizes it answers and honours, the VUIDs only memory or parameters decide, the instance
// references it resolves, and coordinates at the float range's ends.
#include "khr_scene.h"

#include <gtest/gtest.h>

#include <cfloat>
#include <cmath>
#include <cstring>
#include <set>

namespace clastrace::khrtest {
namespace {

ts::TriangleMesh quad(float half, float z) {
    ts::TriangleMesh m;
    m.positions = {{-half, -half, z}, {half, -half, z}, {half, half, z}, {-half, half, z}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}};
    return m;
}

BlasSpec one_mesh(ts::TriangleMesh m) {
    BlasSpec s;
    s.geometries.push_back({std::move(m), {}, VK_GEOMETRY_OPAQUE_BIT_KHR});
    return s;
}

const eng::MemoryAccess* find_access(const eng::ExecutionRecord& r, const std::string& field) {
    for (const auto& a : r.accesses)
        if (a.field == field) return &a;
    return nullptr;
}

TEST(KhrBuild, AccessesNameEveryRangeWithVulkanFieldNames) {
    NvWorld w;
    BlasSpec spec = one_mesh(quad(1, 0));
    spec.geometries.push_back({ts::make_icosphere(1, 0.5f), {}, 0});
    Layout layout;
    layout.first_vertex = 2;
    layout.primitive_offset = 8;
    layout.identity_transform = true;
    eng::KhrBuildInfo info = blas_info(w, spec, layout);
    const auto r = build(w, info);
    ASSERT_TRUE(r.ops[0].executed) << (r.findings.empty() ? "" : r.findings[0].message);
    EXPECT_TRUE(r.findings.empty()) << r.findings[0].rule << ": " << r.findings[0].message;
    const std::string g1 = "pInfos[0].pGeometries[1].geometry.triangles.";
    const eng::MemoryAccess* v = find_access(r, g1 + "vertexData");
    const eng::MemoryAccess* i = find_access(r, g1 + "indexData");
    const eng::MemoryAccess* t = find_access(r, g1 + "transformData");
    const eng::MemoryAccess* s = find_access(r, "pInfos[0].scratchData");
    const eng::MemoryAccess* d = find_access(r, "pInfos[0].dstAccelerationStructure");
    ASSERT_TRUE(v && i && t && s && d);
    const auto& tri = info.geometries[1].triangles;
    // Vertices [firstVertex, maxVertex], indices after primitiveOffset, the transform at
    // transformOffset.
    EXPECT_EQ(v->begin, tri.vertex_data + 2 * 12);
    EXPECT_EQ(v->end, tri.vertex_data + (uint64_t(tri.max_vertex) + 1) * 12);
    EXPECT_EQ(i->begin, tri.index_data + 8);
    EXPECT_EQ(i->end - i->begin, info.ranges[1].primitive_count * 12ull);
    EXPECT_EQ(t->begin, tri.transform_data + 16);
    EXPECT_EQ(t->end - t->begin, 48u);
    EXPECT_FALSE(v->is_write);
    EXPECT_EQ(v->access, eng::kAccessInputBuffer);
    EXPECT_TRUE(s->is_write);
    EXPECT_EQ(s->access, eng::kAccessScratch);
    EXPECT_TRUE(d->is_write);
    EXPECT_EQ(d->begin, info.dst.address);
    EXPECT_EQ(d->end, info.dst.address + r.ops[0].dst_size);
    for (const auto& a : r.accesses) EXPECT_EQ(a.op_index, 0) << a.field;
    EXPECT_NE(find_access(r, "pInfos[0].pGeometries[0].geometry.triangles.vertexData"), nullptr);
}

TEST(KhrBuild, TopLevelAccessesNameInstancesPointersAndBlas) {
    NvWorld w;
    eng::KhrBuildInfo b = blas_info(w, one_mesh(quad(1, 0)), {});
    ASSERT_TRUE(build(w, b).ops[0].executed);
    std::vector<InstanceSpec> instances(2);
    const uint64_t data = put_instances(w, instances, {b.dst.address}, true);
    eng::KhrBuildInfo top = tlas_info(data, 2, true);
    const auto r = build(w, top);
    ASSERT_TRUE(r.ops[0].executed);
    const std::string base = "pInfos[0].pGeometries[0].geometry.instances.data";
    EXPECT_NE(find_access(r, base), nullptr);
    EXPECT_NE(find_access(r, base + "[1]->"), nullptr);
    const eng::MemoryAccess* blas = find_access(r, base + "[0].accelerationStructureReference");
    ASSERT_NE(blas, nullptr);
    EXPECT_EQ(blas->begin, b.dst.address);
    EXPECT_EQ(blas->access, eng::kAccessObjectRead);
}

TEST(KhrBuild, SizesBoundTheObjectAndATooSmallDstIsReported) {
    NvWorld w;
    const BlasSpec spec = one_mesh(ts::make_icosphere(2, 1.0f));
    eng::KhrBuildInfo info = blas_info(w, spec, {});
    const uint32_t count = info.ranges[0].primitive_count;
    const auto sizes = eng::khr_build_sizes(info.type, info.geometries, std::vector{count});
    EXPECT_GT(sizes.acceleration_structure_size, 96u);
    EXPECT_GT(sizes.build_scratch_size, 0u);
    EXPECT_GT(sizes.update_scratch_size, 0u);
    // Queried for fewer primitives than the build uses: dst too small (10126), nothing written.
    const auto small = eng::khr_build_sizes(info.type, info.geometries, std::vector{count / 2});
    info.dst = make_object(w, info.type, small.acceleration_structure_size);
    auto r = build(w, info);
    EXPECT_TRUE(has(r, eng::kVuidKhrDstSize));
    EXPECT_FALSE(r.ops[0].executed);
    // Queried for more: fine, and the object fits the answer.
    const auto big = eng::khr_build_sizes(info.type, info.geometries, std::vector{count * 2});
    info.dst = make_object(w, info.type, big.acceleration_structure_size);
    r = build(w, info);
    ASSERT_TRUE(r.ops[0].executed);
    EXPECT_LE(r.ops[0].dst_size, sizes.acceleration_structure_size);
}

TEST(KhrBuild, ScratchTooSmallAndMisalignedAreReported) {
    NvWorld w;
    eng::KhrBuildInfo info = blas_info(w, one_mesh(quad(1, 0)), {});
    const auto sizes = eng::khr_build_sizes(info.type, info.geometries, std::vector{2u});
    info.dst = make_object(w, info.type, sizes.acceleration_structure_size);
    info.scratch_address = w.alloc(sizes.build_scratch_size, "scratch") + 64;
    info.scratch_available = sizes.build_scratch_size - 64;
    const auto r = eng::execute_khr_build({{info}}, w.memory);
    EXPECT_TRUE(has(r, eng::kVuidKhrBuildScratch));
    EXPECT_TRUE(has(r, eng::kVuidKhrScratchAlignment));
}

TEST(KhrBuild, MisalignedGeometryAddressesNameTheirVuids) {
    NvWorld w;
    eng::KhrBuildInfo info = blas_info(w, one_mesh(quad(1, 0)), {});
    info.geometries[0].triangles.vertex_data += 2;
    info.geometries[0].triangles.index_data += 2;
    info.geometries[0].triangles.transform_data = w.alloc(64, "transform") + 8;
    EXPECT_TRUE(has(build(w, info), eng::kVuidKhrVertexAlignment));
    info.dst = {};
    EXPECT_TRUE(has(build(w, info), eng::kVuidKhrIndexAlignment));
    info.dst = {};
    EXPECT_TRUE(has(build(w, info), eng::kVuidKhrTransformAlignment));
    BlasSpec boxes;
    boxes.aabbs = true;
    boxes.geometries.push_back({{}, nvtest::random_boxes(4, 1), 0});
    eng::KhrBuildInfo aabbs = blas_info(w, boxes, {});
    aabbs.geometries[0].aabbs.data += 4;
    EXPECT_TRUE(has(build(w, aabbs), eng::kVuidKhrAabbAlignment));
    eng::KhrBuildInfo packed = tlas_info(w.alloc(64, "instances") + 8, 0, false);
    EXPECT_TRUE(has(build(w, packed), eng::kVuidKhrInstancesAlignment));
    eng::KhrBuildInfo pointers = tlas_info(w.alloc(64, "pointers") + 4, 0, true);
    EXPECT_TRUE(has(build(w, pointers), eng::kVuidKhrPointersAlignment));
}

TEST(KhrBuild, InstancesNamingNoBuiltBlasAreLeftOutWithTheirRule) {
    NvWorld w;
    eng::KhrBuildInfo b = blas_info(w, one_mesh(quad(1, 0)), {});
    ASSERT_TRUE(build(w, b).ops[0].executed);
    const uint64_t never_built = w.alloc(4096, "empty buffer");
    std::vector<InstanceSpec> instances(3);
    instances[1].blas = 1;
    instances[2].blas = 2;
    const uint64_t data =
        put_instances(w, instances, {b.dst.address, never_built, 0xDEAD0000}, false);
    eng::KhrBuildInfo top = tlas_info(data, 3, false);
    eng::KhrBuildOptions options;
    options.resolve_reference = [&](uint64_t a) -> std::optional<uint64_t> {
        if (a == 0xDEAD0000) return std::nullopt;
        return a;
    };
    const auto r = build(w, top, options);
    ASSERT_TRUE(r.ops[0].executed);
    EXPECT_TRUE(has(r, eng::kRuleKhrBlasNotBuilt));
    EXPECT_TRUE(has(r, eng::kVuidKhrReference));
    std::vector<eng::Finding> findings;
    auto scene = eng::NvScene::open(w.memory, top.dst.address, &findings, nullptr);
    ASSERT_TRUE(scene);
    EXPECT_EQ(scene->instances_reached(), 1u);
    EXPECT_TRUE(scene->closest(eng::Ray{{0.1f, 0.2f, -1}, 0, {0, 0, 1}, 10}, 0, 0xFF).hit);
}

TEST(KhrBuild, InstanceCountAboveTheLimitIsReported) {
    NvWorld w;
    eng::KhrBuildInfo top = tlas_info(w.alloc(64 * 8, "instances"), 8, false);
    eng::KhrBuildOptions options;
    options.limits.max_instance_count = 4;
    const auto r = build(w, top, options);
    EXPECT_TRUE(has(r, eng::kVuidKhrInstanceCount));
    EXPECT_FALSE(r.ops[0].executed);
}

TEST(KhrBuild, InfosOfOneCommandMustNotAlias) {
    NvWorld w;
    eng::KhrBuildInfo a = blas_info(w, one_mesh(quad(1, 0)), {});
    const auto sizes = eng::khr_build_sizes(a.type, a.geometries, std::vector{2u});
    a.dst = make_object(w, a.type, sizes.acceleration_structure_size);
    a.scratch_address = w.alloc(sizes.build_scratch_size, "scratch");
    a.scratch_available = sizes.build_scratch_size;
    eng::KhrBuildInfo b = a;  // the same dst and scratch
    const auto r = eng::execute_khr_build({{a, b}}, w.memory);
    EXPECT_TRUE(has(r, eng::kVuidKhrSameDst));
    EXPECT_TRUE(has(r, eng::kVuidKhrScratchOverlapsScratch));
    EXPECT_EQ(r.op_count, 2u);
    // Apart, both build, each op naming its own index.
    b.dst = make_object(w, b.type, sizes.acceleration_structure_size);
    b.scratch_address = w.alloc(sizes.build_scratch_size, "scratch");
    const auto ok = eng::execute_khr_build({{a, b}}, w.memory);
    EXPECT_TRUE(ok.findings.empty()) << ok.findings[0].rule;
    EXPECT_TRUE(ok.ops[0].executed && ok.ops[1].executed);
    EXPECT_NE(find_access(ok, "pInfos[1].dstAccelerationStructure"), nullptr);
}

// A top level and the bottom level it names in one command: the spec forbids it (None-03407).
TEST(KhrBuild, ATopLevelNamingAnotherInfosDstIsReported) {
    NvWorld w;
    eng::KhrBuildInfo b = blas_info(w, one_mesh(quad(1, 0)), {});
    ASSERT_TRUE(build(w, b).ops[0].executed);
    eng::KhrBuildInfo rebuild = b;
    rebuild.scratch_address = w.alloc(b.scratch_available, "scratch");
    std::vector<InstanceSpec> instances(1);
    eng::KhrBuildInfo top =
        tlas_info(put_instances(w, instances, {b.dst.address}, false), 1, false);
    const auto sizes = eng::khr_build_sizes(top.type, top.geometries, std::vector{1u});
    top.dst = make_object(w, top.type, sizes.acceleration_structure_size);
    top.scratch_address = w.alloc(sizes.build_scratch_size, "scratch");
    top.scratch_available = sizes.build_scratch_size;
    const auto r = eng::execute_khr_build({{rebuild, top}}, w.memory);
    EXPECT_TRUE(has(r, eng::kVuidKhrDstInOtherInstances));
}

TEST(KhrBuild, UnsupportedVertexFormatAndWrongDstTypeStopTheInfo) {
    NvWorld w;
    eng::KhrBuildInfo info = blas_info(w, one_mesh(quad(1, 0)), {});
    info.geometries[0].triangles.vertex_format = VK_FORMAT_R64G64B64_SFLOAT;
    auto r = build(w, info);
    EXPECT_TRUE(has(r, eng::kRuleUnsupportedFormat));
    EXPECT_FALSE(r.ops[0].executed);
    info = blas_info(w, one_mesh(quad(1, 0)), {});
    info.dst = make_object(w, VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, 1 << 16);
    r = build(w, info);
    EXPECT_TRUE(has(r, eng::kVuidKhrBottomDstType));
    EXPECT_FALSE(r.ops[0].executed);
}

// Indices past maxVertex make their triangle inactive; NaN X makes it inactive silently.
TEST(KhrBuild, IndicesAboveMaxVertexAndNanXAreInactive) {
    NvWorld w;
    ts::TriangleMesh m = quad(1, 0);
    m.positions.push_back({std::nanf(""), 0, 0});
    m.triangles.push_back({4, 1, 2});  // NaN X: inactive, no finding
    eng::KhrBuildInfo info = blas_info(w, one_mesh(m), {});
    info.geometries[0].triangles.max_vertex = 4;
    auto r = build(w, info);
    ASSERT_TRUE(r.ops[0].executed);
    EXPECT_TRUE(r.findings.empty()) << r.findings[0].message;
    auto h = eng::read_nv_header(w.memory.read_bytes(info.dst.address, 96, {}), nullptr);
    ASSERT_TRUE(h);
    EXPECT_EQ(h->primitive_count, 2u);
    info = blas_info(w, one_mesh(m), {});
    info.geometries[0].triangles.max_vertex = 2;  // triangle 1 uses vertex 3, triangle 2 vertex 4
    r = build(w, info);
    ASSERT_TRUE(r.ops[0].executed);
    EXPECT_TRUE(has(r, eng::kRuleKhrIndexAboveMaxVertex));
    h = eng::read_nv_header(w.memory.read_bytes(info.dst.address, 96, {}), nullptr);
    EXPECT_EQ(h->primitive_count, 1u);
}

// 1e30 to 3e38 and 1e-30 to 1e-38 (beyond what Embree's agreement test can take): a ray
// straight at the quad keeps its exact t.
TEST(KhrBuild, HugeAndTinyCoordinatesKeepTheirT) {
    for (float z : {1e30f, 1e37f, 3.0e38f, 1e-30f, 1e-38f}) {
        NvWorld w;
        eng::KhrBuildInfo info = blas_info(w, one_mesh(quad(z, z)), {});
        ASSERT_TRUE(build(w, info).ops[0].executed);
        auto scene = eng::NvScene::open_bottom(w.memory, info.dst.address, nullptr);
        ASSERT_TRUE(scene);
        const eng::NvHit hit =
            scene->closest(eng::Ray{{0.25f * z, -0.5f * z, 0}, 0, {0, 0, 1}, FLT_MAX}, 0, 0xFF);
        ASSERT_TRUE(hit.hit) << z;
        EXPECT_FLOAT_EQ(hit.t, z);
    }
}

}  // namespace
}  // namespace clastrace::khrtest
