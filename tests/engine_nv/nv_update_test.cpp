// SPDX-License-Identifier: Apache-2.0
// Update (refit) of NV objects: the refit tree answers like a fresh build of the moved
// input, in place and into another object; topology changes, active/inactive changes and
// a src built without ALLOW_UPDATE are reported.
#include "nv_scene.h"

#include <clastrace/testsupport/rays.h>

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

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

constexpr VkBuildAccelerationStructureFlagsNV kAllowUpdate =
    VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_NV;

// Hits of `rays` through both scenes agree: same primitive and t, or both miss.
void expect_same_answers(const eng::NvScene& a, const eng::NvScene& b,
                         const std::vector<ts::TestRay>& rays, size_t* hits) {
    *hits = 0;
    for (const auto& tr : rays) {
        const eng::Ray ray{{tr.origin[0], tr.origin[1], tr.origin[2]},
                           0.0f,
                           {tr.direction[0], tr.direction[1], tr.direction[2]},
                           tr.tmax};
        const eng::NvHit x = a.closest(ray, 0, 0xFF), y = b.closest(ray, 0, 0xFF);
        ASSERT_EQ(x.hit, y.hit);
        if (!x.hit) continue;
        ++*hits;
        ASSERT_EQ(x.t, y.t);
        ASSERT_EQ(x.instance_index, y.instance_index);
        ASSERT_EQ(x.primitive_index, y.primitive_index);
    }
}

void move_mesh(ts::TriangleMesh& m, float t) {
    for (auto& p : m.positions)
        p = {p[0] * 1.3f + t, p[1] * (1.0f + 0.2f * std::sin(p[0] * 3)), p[2] - 0.5f * t};
}

TEST(NvUpdate, BottomLevelRefitAnswersLikeAFreshBuildInPlaceAndIntoAnotherObject) {
    for (bool in_place : {true, false}) {
        NvWorld w;
        BlasSpec spec;
        spec.geometries.push_back({ts::make_icosphere(3, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
        spec.geometries.push_back(
            {ts::make_torus(16, 8, 2.0f, 0.3f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
        auto info = w.blas_info(spec, kAllowUpdate);
        auto obj = w.make_object(info, "blas");
        ASSERT_TRUE(w.build(info, obj).ops[0].executed);
        for (auto& g : spec.geometries) move_mesh(g.mesh, 0.7f);
        auto moved = w.blas_info(spec, kAllowUpdate);  // new buffers, same counts
        auto dst = in_place ? obj : w.make_object(moved, "dst");
        const auto r = w.build(moved, dst, 0, true, &obj);
        ASSERT_TRUE(r.ops[0].executed) << rules(r);
        EXPECT_TRUE(r.findings.empty()) << rules(r);
        bool reads_src = false;
        for (const auto& a : r.accesses) reads_src |= a.field == "src" && a.begin == obj.address;
        EXPECT_TRUE(reads_src);
        auto fresh = w.make_object(moved, "fresh");
        ASSERT_TRUE(w.build(moved, fresh).ops[0].executed);
        auto a = eng::NvScene::open_bottom(w.memory, dst.address, nullptr);
        auto b = eng::NvScene::open_bottom(w.memory, fresh.address, nullptr);
        ASSERT_TRUE(a && b);
        ts::Bounds box;
        box.extend({-4, -4, -4});
        box.extend({4, 4, 4});
        size_t hits = 0;
        expect_same_answers(*a, *b, ts::random_rays(box, 5000, 2), &hits);
        EXPECT_GT(hits, 500u);
        // The refit keeps src's tree: same node count, update counter advanced.
        auto hv = eng::read_nv_header(w.memory.read_bytes(dst.address, 96, {}), nullptr);
        auto hs = eng::read_nv_header(w.memory.read_bytes(fresh.address, 96, {}), nullptr);
        ASSERT_TRUE(hv && hs);
        EXPECT_EQ(hv->update_count, 1u);
        EXPECT_EQ(hs->update_count, 0u);
    }
}

TEST(NvUpdate, TopLevelRefitFollowsMovedInstances) {
    std::vector<BlasSpec> blas(2);
    blas[0].geometries.push_back({ts::make_icosphere(2, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    blas[1].geometries.push_back(
        {ts::make_torus(12, 8, 1.0f, 0.3f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    auto instances = random_instances(40, 2, 4.0f, 17);
    auto s = build_scene(blas, instances, kAllowUpdate);
    ASSERT_TRUE(s->findings.empty());
    for (auto& in : instances) {
        in.transform[3] += 1.5f;
        in.transform[7] *= -1.0f;
    }
    std::vector<uint64_t> handles{s->blas[0].handle, s->blas[1].handle};
    auto bytes = s->world.instance_bytes(instances, handles);
    const uint64_t ia = s->world.put(bytes.data(), bytes.size(), "moved instances");
    eng::NvObjectInfo top = *s->tlas.created;
    const auto r = s->world.build(top, s->tlas, ia, true, &s->tlas);
    ASSERT_TRUE(r.ops[0].executed) << rules(r);
    EXPECT_TRUE(r.findings.empty()) << rules(r);
    auto fresh = s->world.make_object(top, "fresh");
    ASSERT_TRUE(s->world.build(top, fresh, ia).ops[0].executed);
    auto a = eng::NvScene::open(s->world.memory, s->tlas.address, nullptr, nullptr);
    auto b = eng::NvScene::open(s->world.memory, fresh.address, nullptr, nullptr);
    ASSERT_TRUE(a && b);
    ts::Bounds box;
    box.extend({-7, -7, -7});
    box.extend({7, 7, 7});
    size_t hits = 0;
    expect_same_answers(*a, *b, ts::random_rays(box, 8000, 5), &hits);
    EXPECT_GT(hits, 1000u);
    // And against Embree for the moved scene.
    EmbreeNvScene embree(blas, instances);
    Agreement agreement;
    for (const auto& tr : ts::random_rays(box, 8000, 6)) {
        const eng::Ray ray{{tr.origin[0], tr.origin[1], tr.origin[2]},
                           0.0f,
                           {tr.direction[0], tr.direction[1], tr.direction[2]},
                           tr.tmax};
        classify(agreement, a->closest(ray, 0, 0xFF), embree.closest(ray, 0, 0xFF), 1e-5, "moved");
    }
    EXPECT_EQ(agreement.disagree, 0u) << agreement.summary();
}

TEST(NvUpdate, TopologyChangeIsReportedAndRebuilt) {
    NvWorld w;
    BlasSpec spec;
    spec.geometries.push_back({ts::make_icosphere(2, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    auto info = w.blas_info(spec, kAllowUpdate);
    auto obj = w.make_object(info, "blas");
    ASSERT_TRUE(w.build(info, obj).ops[0].executed);
    // Fewer triangles (dst was created larger, so 02488 holds).
    auto fewer = info;
    fewer.geometries[0].triangles.index_count -= 30;
    auto r = w.build(fewer, obj, 0, true, &obj);
    EXPECT_TRUE(has(r, eng::kRuleNvUpdateTopology)) << rules(r);
    ASSERT_TRUE(r.ops[0].executed);
    auto h = eng::read_nv_header(w.memory.read_bytes(obj.address, 96, {}), nullptr);
    EXPECT_EQ(h->primitive_count, spec.geometries[0].mesh.triangles.size() - 10);
    EXPECT_EQ(h->update_count, 0u);  // a rebuild, not a refit
    // Other vertex format, other flags.
    auto other = info;
    other.geometries[0].flags = 0;
    r = w.build(other, obj, 0, true, &obj);
    EXPECT_TRUE(has(r, eng::kRuleNvUpdateTopology)) << rules(r);
    // Top-level src for a bottom-level update.
    std::vector<BlasSpec> blas{spec};
    auto s = build_scene(blas, std::vector<InstanceSpec>(2), kAllowUpdate);
    eng::NvObjectBinding tlas_as_src = s->tlas;
    auto info2 = s->world.blas_info(spec, kAllowUpdate);
    auto dst2 = s->world.make_object(info2, "dst");
    r = s->world.build(info2, dst2, 0, true, &tlas_as_src);
    EXPECT_TRUE(has(r, eng::kRuleNvUpdateTopology)) << rules(r);
    // Other instance count.
    eng::NvObjectInfo top = *s->tlas.created;
    top.instance_count = 1;
    r = s->world.build(top, s->tlas, s->instance_address, true, &s->tlas);
    EXPECT_TRUE(has(r, eng::kRuleNvUpdateTopology)) << rules(r);
}

TEST(NvUpdate, ActiveStateChangesAndMissingAllowUpdate) {
    NvWorld w;
    BlasSpec spec;
    spec.geometries.push_back({ts::make_icosphere(1, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    spec.geometries[0].mesh.positions[0][0] =
        std::nanf("");  // triangles using vertex 0 start inactive
    auto info = w.blas_info(spec, kAllowUpdate);
    auto obj = w.make_object(info, "blas");
    auto r = w.build(info, obj);
    ASSERT_TRUE(r.ops[0].executed);
    EXPECT_TRUE(r.findings.empty())
        << rules(r);  // X NaN is the spec's inactive triangle, no finding
    BlasSpec changed = spec;
    changed.geometries[0].mesh.positions[0][0] = 0.5f;           // inactive -> active
    changed.geometries[0].mesh.positions[5][0] = std::nanf("");  // active -> inactive
    auto info2 = w.blas_info(changed, kAllowUpdate);
    r = w.build(info2, obj, 0, true, &obj);
    EXPECT_TRUE(has(r, eng::kVuidNvMadeActive)) << rules(r);
    EXPECT_TRUE(has(r, eng::kVuidNvMadeInactive)) << rules(r);
    EXPECT_TRUE(r.ops[0].executed);
    // Instances: reference 0 <-> not.
    std::vector<BlasSpec> blas{spec};
    std::vector<InstanceSpec> inst(3);
    inst[1].blas = -1;
    auto s = build_scene(blas, inst, kAllowUpdate);
    inst[1].blas = 0;
    inst[2].blas = -1;
    auto bytes = s->world.instance_bytes(inst, {s->blas[0].handle});
    const uint64_t ia = s->world.put(bytes.data(), bytes.size(), "i");
    r = s->world.build(*s->tlas.created, s->tlas, ia, true, &s->tlas);
    EXPECT_TRUE(has(r, eng::kVuidNvMadeActive)) << rules(r);
    EXPECT_TRUE(has(r, eng::kVuidNvMadeInactive)) << rules(r);
    // src built without ALLOW_UPDATE, though the binding claims it: the bytes decide.
    NvWorld w2;
    auto info3 = w2.blas_info(spec, 0);
    auto plain = w2.make_object(info3, "plain");
    ASSERT_TRUE(w2.build(info3, plain).ops[0].executed);
    plain.built_flags = kAllowUpdate;
    r = w2.build(info3, plain, 0, true, &plain);
    EXPECT_TRUE(has(r, eng::kVuidNvUpdateNotAllowed)) << rules(r);
    EXPECT_FALSE(r.ops[0].executed);
    // src aliasing dst without being the same object.
    auto info4 = w2.blas_info(spec, kAllowUpdate);
    auto a = w2.make_object(info4, "a");
    ASSERT_TRUE(w2.build(info4, a).ops[0].executed);
    eng::NvObjectBinding alias = a;
    alias.handle = a.handle + 1;
    alias.address = a.address + 256;
    alias.size = a.size - 256;
    r = w2.build(info4, alias, 0, true, &a);
    EXPECT_TRUE(has(r, eng::kVuidNvUpdateAliasing)) << rules(r);
    // src that holds no object.
    eng::NvObjectBinding empty = w2.make_object(info4, "never built");
    empty.built = true;
    empty.built_flags = kAllowUpdate;
    r = w2.build(info4, a, 0, true, &empty);
    EXPECT_TRUE(has(r, eng::kRuleNvSrcNotBuilt)) << rules(r);
}

}  // namespace
}  // namespace clastrace::nvtest
