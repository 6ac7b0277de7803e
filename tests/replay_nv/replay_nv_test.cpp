// SPDX-License-Identifier: Apache-2.0
// Replay of vkCmdBuildAccelerationStructureNV / vkCmdCopyMemoryToAccelerationStructureKHR
// traces written here with TraceWriter as a driver capture would be, with RayQueryCheck
// records whose "driver" answers come from Embree: every object rebuilt, driver handles
// translated, the rays agree; wrong answers, unknown handles, other drivers' blobs and
// hazards are reported.
#include "nv_trace_builder.h"
#include "trace_files.h"

#include <clastrace/engine/nv_serialize.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/testsupport/rays.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstring>
#include <filesystem>
#include <random>

namespace clastrace::nvtest {
namespace {

using test::replay_file;

std::string temp_path(const std::string& name) { return test::temp_trace_path("replay_nv", name); }

size_t count_rule(const replay::ReplayReport& r, const std::string& rule) {
    size_t n = 0;
    for (const auto& f : r.findings) n += f.rule == rule;
    for (const auto& note : r.notes) n += note.rule == rule;  // the replay's own limits
    return n;
}

std::vector<BlasSpec> scene_blas() {
    std::vector<BlasSpec> out(3);
    out[0].geometries.push_back({ts::make_icosphere(2, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    out[1].geometries.push_back({ts::make_torus(16, 8, 1.0f, 0.3f), {}, 0});
    out[1].geometries.push_back(
        {ts::make_random_soup(100, 3, 0.5f, 0.3f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    out[2].aabbs = true;
    out[2].geometries.push_back({{}, random_boxes(40, 9), VK_GEOMETRY_OPAQUE_BIT_NV});
    return out;
}

struct RaySet {
    std::vector<eng::Ray> rays;
    std::vector<uint32_t> flags, masks;
    std::vector<RefHit> answers;
};
RaySet driver_rays(const std::vector<BlasSpec>& blas, const std::vector<InstanceSpec>& instances,
                   size_t n, uint64_t seed) {
    EmbreeNvScene embree(blas, instances);
    ts::Bounds box;
    box.extend({-7, -7, -7});
    box.extend({7, 7, 7});
    RaySet s;
    std::mt19937_64 rng(seed);
    const uint32_t flag_sets[] = {0, eng::kRayFlagOpaque, eng::kRayFlagCullBackFacingTriangles,
                                  eng::kRayFlagCullNoOpaque};
    for (const auto& t : ts::random_rays(box, n, seed)) {
        const eng::Ray r{{t.origin[0], t.origin[1], t.origin[2]},
                         0.0f,
                         {t.direction[0], t.direction[1], t.direction[2]},
                         t.tmax};
        const uint32_t f = flag_sets[rng() % 4], m = rng() % 3 ? 0xFFu : uint32_t(rng() & 0xFF);
        s.rays.push_back(r);
        s.flags.push_back(f);
        s.masks.push_back(m);
        s.answers.push_back(embree.closest(r, f, m));
    }
    return s;
}

struct Written {
    std::vector<BlasSpec> blas;
    std::vector<InstanceSpec> instances;
    std::vector<NvTraceBuilder::Object> blas_objects;
    NvTraceBuilder::Object tlas;
};

// BLAS builds, a barrier, the TLAS build, submit; instance records carry driver handles.
Written write_scene(NvTraceBuilder& t, size_t instance_count, uint64_t seed,
                    uint64_t bad_handle = 0) {
    Written w;
    w.blas = scene_blas();
    w.instances = random_instances(instance_count, int(w.blas.size()), 4.0f, seed);
    std::vector<uint64_t> handles;
    for (const BlasSpec& b : w.blas) {
        auto info = t.blas_info(b);
        auto obj = t.create(info, 1000);  // the driver's (smaller) object size
        t.build(info, obj);
        w.blas_objects.push_back(obj);
        handles.push_back(obj.driver_handle);
    }
    t.barrier();
    NvWorld scratch_world;
    auto bytes = scratch_world.instance_bytes(w.instances, handles);
    if (bad_handle) std::memcpy(bytes.data() + 56, &bad_handle, 8);
    const uint64_t ib = t.buffer(bytes.data(), bytes.size());
    auto info = NvTraceBuilder::tlas_info(uint32_t(instance_count));
    w.tlas = t.create(info, 4000);
    t.build(info, w.tlas, ib);
    t.submit();
    return w;
}

TEST(ReplayNv, DriverTraceRebuildsTranslatesHandlesAndAgreesWithTheDriversRays) {
    const std::string path = temp_path("driver.clt");
    Written w;
    {
        NvTraceBuilder t(path, false);
        w = write_scene(t, 30, 5);
        const RaySet s = driver_rays(w.blas, w.instances, 20000, 7);
        t.ray_check(w.tlas, s.rays, s.flags, s.masks, s.answers, "camera");
        t.finish();
    }
    const replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
    EXPECT_TRUE(r.not_replayed.empty());
    EXPECT_EQ(r.counts.nv_builds, 4u);
    EXPECT_GE(r.counts.handles_translated, 3u);
    ASSERT_EQ(r.nv_sizes.size(), 4u);
    for (const auto& s : r.nv_sizes) {
        EXPECT_GT(s.engine_bytes, 0u);
        EXPECT_LE(s.engine_bytes, s.engine_object);
        EXPECT_GT(s.driver_object, 0u);  // captured requirement shown side by side
    }
    EXPECT_TRUE(r.nv_sizes[3].top_level);
    EXPECT_EQ(r.nv_sizes[3].primitives, 30u);
    ASSERT_EQ(r.ray_checks.size(), 1u);
    const auto& c = r.ray_checks[0];
    EXPECT_TRUE(c.checked) << c.why_not;
    EXPECT_EQ(c.rays, 20000u);
    EXPECT_EQ(c.disagree, 0u) << replay::format_text(r);
    EXPECT_GT(c.agree_hit, 3000u);
    EXPECT_GT(c.agree_miss, 1000u);
    EXPECT_LT(c.tie + c.edge, 100u);
    EXPECT_GT(r.counts.accesses, 8u);
    // The JSON form carries both tables.
    const nlohmann::json j = replay::to_json(r);
    ASSERT_EQ(j["ray_checks"].size(), 1u);
    EXPECT_EQ(j["ray_checks"][0]["rays"], 20000);
    EXPECT_EQ(j["ray_checks"][0]["disagree"], 0);
    EXPECT_EQ(j["nv_sizes"].size(), 4u);
    EXPECT_EQ(j["counts"]["nv_builds"], 4);
    EXPECT_NE(replay::format_text(r).find("ray check 'camera'"), std::string::npos);
    std::filesystem::remove(path);
}

TEST(ReplayNv, WrongDriverAnswersAreCountedAndReported) {
    const std::string path = temp_path("wrong.clt");
    {
        NvTraceBuilder t(path, false);
        Written w = write_scene(t, 12, 8);
        RaySet s = driver_rays(w.blas, w.instances, 3000, 2);
        size_t changed = 0;
        for (size_t i = 0; i < s.answers.size() && changed < 20; ++i) {
            RefHit& a = s.answers[i];
            if (!a.hit || a.hit_kind == 0) continue;
            a.t *= 1.01f;                       // another t ...
            if (changed % 2) a.primitive += 1;  // ... and for half of them another primitive
            a.u = a.v = 0.3f;                   // away from the edges
            ++changed;
        }
        // A miss the driver reported as a hit far from any edge.
        for (size_t i = 0; i < s.answers.size(); ++i)
            if (!s.answers[i].hit) {
                s.answers[i] = RefHit{true, 5.0f, 0, 0, 0, 0, eng::kHitKindFrontFacing, 0.3f, 0.3f};
                break;
            }
        t.ray_check(w.tlas, s.rays, s.flags, s.masks, s.answers, "tampered");
        t.finish();
    }
    const replay::ReplayReport r = replay_file(path);
    ASSERT_EQ(r.ray_checks.size(), 1u);
    EXPECT_EQ(r.ray_checks[0].disagree, 21u) << replay::format_text(r);
    EXPECT_EQ(count_rule(r, "CLASTRACE-replay-ray-check-disagrees"), 21u);
    EXPECT_FALSE(r.clean());
    for (const auto& f : r.findings)
        if (f.rule == "CLASTRACE-replay-ray-check-disagrees") {
            EXPECT_NE(f.message.find("tampered"), std::string::npos);
            EXPECT_GE(f.op_index, 0);
        }
    std::filesystem::remove(path);
}

TEST(ReplayNv, InstanceHandleThatTranslatesToNothingIsAFinding) {
    const std::string path = temp_path("badhandle.clt");
    {
        NvTraceBuilder t(path, false);
        write_scene(t, 6, 3, /*bad_handle=*/0x1234567800ull);
        t.finish();
    }
    const replay::ReplayReport r = replay_file(path);
    EXPECT_EQ(count_rule(
                  r, "VUID-vkCmdBuildAccelerationStructureNV-accelerationStructureReference-12264"),
              1u)
        << replay::format_text(r);
}

TEST(ReplayNv, TheCapturingDevicesLimitsApply) {
    const std::string path = temp_path("limits.clt");
    {
        NvTraceBuilder t(path, false, /*max_instance_count=*/4);
        write_scene(t, 6, 3);
        t.finish();
    }
    const replay::ReplayReport r = replay_file(path);
    EXPECT_EQ(count_rule(r, "VUID-VkAccelerationStructureInfoNV-instanceCount-02422"), 1u)
        << replay::format_text(r);
    // A deserialization on a device whose recorded extensions lack VK_KHR_acceleration_structure.
    for (bool with_khr : {false, true}) {
        {
            std::vector<std::string> ext{"VK_NV_ray_tracing"};
            if (with_khr) ext.push_back("VK_KHR_acceleration_structure");
            NvTraceBuilder t(path, false, 0, ext);
            Written w = write_scene(t, 2, 3);
            std::vector<uint8_t> blob(256, 0);
            const uint64_t src = t.buffer(blob.data(), blob.size());
            t.deserialize(src, w.tlas);
            t.submit();
            t.finish();
        }
        const replay::ReplayReport r2 = replay_file(path);
        EXPECT_EQ(count_rule(
                      r2,
                      "VUID-vkCmdCopyMemoryToAccelerationStructureKHR-accelerationStructure-08927"),
                  with_khr ? 0u : 1u)
            << replay::format_text(r2);
    }
    std::filesystem::remove(path);
}

TEST(ReplayNv, DeserializedEngineBlobTranslatesItsHandleListAndAgrees) {
    const std::string path = temp_path("deserialize.clt");
    {
        NvTraceBuilder t(path, false);
        Written w = write_scene(t, 20, 11);
        // The engine's serialized TLAS whose handle list carries the driver handles.
        NvWorld side;
        std::unordered_map<uint64_t, uint64_t> to_address;
        std::vector<uint64_t> handles;
        for (size_t b = 0; b < w.blas.size(); ++b) {
            auto info = side.blas_info(w.blas[b]);
            auto obj = side.make_object(info, "blas");
            side.build(info, obj);
            to_address[w.blas_objects[b].driver_handle] = obj.address;
            handles.push_back(w.blas_objects[b].driver_handle);
        }
        auto bytes = side.instance_bytes(w.instances, handles);
        const uint64_t ia = side.put(bytes.data(), bytes.size(), "instances");
        eng::NvObjectInfo top;
        top.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
        top.instance_count = uint32_t(w.instances.size());
        auto tlas = side.make_object(top, "tlas");
        eng::NvBuildOptions o;
        o.resolve_reference = [&](uint64_t h) -> std::optional<uint64_t> {
            return to_address.at(h);
        };
        ASSERT_TRUE(side.build(top, tlas, ia, false, nullptr, o).ops[0].executed);
        const auto blob = eng::serialize_nv_object(side.memory, tlas.address, nullptr);
        ASSERT_FALSE(blob.empty());
        const uint64_t src = t.buffer(blob.data(), blob.size());
        auto copy = t.create(NvTraceBuilder::tlas_info(uint32_t(w.instances.size())), blob.size());
        t.deserialize(src, copy);
        t.submit();
        const RaySet s = driver_rays(w.blas, w.instances, 5000, 4);
        t.ray_check(copy, s.rays, s.flags, s.masks, s.answers, "deserialized");
        t.finish();
    }
    const replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
    EXPECT_EQ(r.counts.deserializations, 1u);
    ASSERT_EQ(r.ray_checks.size(), 1u);
    EXPECT_TRUE(r.ray_checks[0].checked) << r.ray_checks[0].why_not;
    EXPECT_EQ(r.ray_checks[0].disagree, 0u);
    EXPECT_GT(r.ray_checks[0].agree_hit, 500u);
}

TEST(ReplayNv, AnotherDriversBlobIsOpaqueButItsHeaderIsChecked) {
    const std::string path = temp_path("foreign.clt");
    {
        NvTraceBuilder t(path, false);
        Written w = write_scene(t, 4, 2);
        // The blob and 64 bytes after it in one buffer (the snapshot reads them all).
        std::vector<uint8_t> blob(56 + 4 * 8 + 512 + 64, 0x5A);
        eng::SerializedHeader h{};
        std::memset(h.driver_uuid, 0x10, 16);
        std::memset(h.compatibility_uuid, 0xDE, 16);
        h.serialized_size = blob.size() - 64;
        h.deserialized_size = 512;
        h.handle_count = 4;
        std::memcpy(blob.data(), &h, sizeof h);
        for (int i = 0; i < 4; ++i) {
            const uint64_t handle = i == 3 ? 0xBADull : w.blas_objects[size_t(i % 3)].driver_handle;
            std::memcpy(blob.data() + 56 + 8 * i, &handle, 8);
        }
        const uint64_t src = t.buffer(blob.data(), blob.size());
        auto copy = t.create(NvTraceBuilder::tlas_info(4),
                             400);  // the driver said 400 bytes: too small for 512
        t.deserialize(src, copy);
        t.barrier();
        t.deserialize(src, copy, VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR,
                      8);  // misaligned source
        t.submit();
        t.ray_check(copy, {eng::Ray{{0, 0, 9}, 0, {0, 0, -1}, 100}}, {0}, {0xFF}, {RefHit{}},
                    "opaque");
        t.finish();
    }
    const replay::ReplayReport r = replay_file(path);
    EXPECT_GE(count_rule(r, "CLASTRACE-serialized-blob-from-another-driver"), 1u)
        << replay::format_text(r);
    EXPECT_GE(count_rule(r, "VUID-VkCopyMemoryToAccelerationStructureInfoKHR-dst-03746"), 1u)
        << replay::format_text(r);
    EXPECT_EQ(count_rule(r, "CLASTRACE-deserialize-handle-names-no-created-object"), 1u)
        << replay::format_text(r);
    EXPECT_EQ(count_rule(r, "VUID-vkCmdCopyMemoryToAccelerationStructureKHR-pInfo-03743"), 1u)
        << replay::format_text(r);
    ASSERT_EQ(r.ray_checks.size(), 1u);
    EXPECT_FALSE(r.ray_checks[0].checked);
    EXPECT_NE(r.ray_checks[0].why_not.find("another driver"), std::string::npos);
}

TEST(ReplayNv, ScratchReuseAndDeserializingIntoAnObjectInUseAreHazards) {
    const std::string path = temp_path("hazard.clt");
    {
        NvTraceBuilder t(path, false);
        auto blas = scene_blas();
        auto info0 = t.blas_info(blas[0]);
        auto info1 = t.blas_info(blas[1]);
        auto a = t.create(info0, 1000), b = t.create(info1, 1000);
        // Both builds share one scratch buffer, no barrier between them.
        const uint64_t scratch = t.buffer(nullptr, 1 << 20);
        t.build(info0, a, 0, false, nullptr, 0, scratch);
        t.build(info1, b, 0, false, nullptr, 0, scratch);
        t.submit();
        // A TLAS over a, then deserializing into a while the TLAS build still reads it.
        std::vector<InstanceSpec> inst(1);
        NvWorld side;
        auto bytes = side.instance_bytes(inst, {a.driver_handle});
        const uint64_t ib = t.buffer(bytes.data(), bytes.size());
        auto tinfo = NvTraceBuilder::tlas_info(1);
        auto tlas = t.create(tinfo, 4000);
        t.build(tinfo, tlas, ib);
        std::vector<uint8_t> blob(256, 0);
        eng::SerializedHeader h{};
        h.serialized_size = 256;
        h.deserialized_size = 100;
        std::memcpy(blob.data(), &h, sizeof h);
        const uint64_t src = t.buffer(blob.data(), blob.size());
        t.deserialize(src, a);
        t.submit();
        t.finish();
    }
    const replay::ReplayReport r = replay_file(path);
    bool dst_hazard = false, scratch_hazard = false;
    for (const auto& hz : r.hazards) {
        const std::string text = hz.format();
        dst_hazard |= text.find("pInfo->dst") != std::string::npos;
        scratch_hazard |= hz.prior.field == "scratch" && hz.later.field == "scratch";
    }
    EXPECT_TRUE(dst_hazard) << replay::format_text(r);
    EXPECT_TRUE(scratch_hazard) << replay::format_text(r);
}

// Hostile creation counts and a hostile deserializedSize end in findings, not allocations.
TEST(ReplayNv, HostileCreationCountsAndDeserializedSizesAllocateNothing) {
    const std::string path = temp_path("hostile.clt");
    {
        NvTraceBuilder t(path, false);
        auto blas = scene_blas();
        auto info = t.blas_info(blas[0]);
        auto huge = info;
        const auto& o = *huge.geometries[0]->triangles;
        huge.geometries[0]->triangles =
            std::make_unique<fbs::GeometryTrianglesNV>(o.vertex_data(), 0, 0xFFFFFFFFu,
                                                       o.vertex_format(), 12, o.index_data(), 0,
                                                       0xFFFFFFFFu, o.index_type(), 0, 0);
        auto obj = t.create(huge, 1000);
        t.build(info, obj);
        std::vector<uint8_t> blob(256, 0);
        eng::SerializedHeader h{};
        std::memcpy(h.driver_uuid, eng::kEngineDriverUuid.data(), 16);
        std::memcpy(h.compatibility_uuid, eng::kEngineNvCompatibilityUuid.data(), 16);
        h.serialized_size = 256;
        h.deserialized_size = 3ull << 30;
        std::memcpy(blob.data(), &h, sizeof h);
        const uint64_t src = t.buffer(blob.data(), blob.size());
        auto small = t.create(info, 1000);
        t.deserialize(src, small);
        t.submit();
        t.finish();
    }
    const replay::ReplayReport r = replay_file(path);
    EXPECT_EQ(count_rule(r, "CLASTRACE-replay-nv-object-over-budget"), 1u)
        << replay::format_text(r);
    EXPECT_GE(count_rule(r, "VUID-VkCopyMemoryToAccelerationStructureInfoKHR-dst-03746") +
                  count_rule(r, "VUID-VkCopyMemoryToAccelerationStructureInfoKHR-src-04960"),
              1u)
        << replay::format_text(r);
    std::filesystem::remove(path);
}

// Hostile instance bytes, handles and counts in a driver trace: the replay finishes.
TEST(ReplayNv, RandomMutationsOfInstanceRecordsNeverCrash) {
    std::mt19937_64 rng(99);
    const std::string path = temp_path("mutant.clt");
    for (int round = 0; round < 40; ++round) {
        {
            NvTraceBuilder t(path, round % 2 == 0);
            auto blas = scene_blas();
            auto info = t.blas_info(blas[rng() % 3]);
            if (rng() % 3 == 0 && !info.geometries.empty()) {
                auto& g = *info.geometries[0];
                const auto& o = *g.triangles;
                g.triangles = std::make_unique<fbs::GeometryTrianglesNV>(
                    o.vertex_data(), o.vertex_offset(),
                    rng() % 2 ? uint32_t(rng()) : o.vertex_count(), o.vertex_format(),
                    rng() % 3 ? rng() : 0, o.index_data(), rng() % 2 ? rng() % 64 : 0,
                    o.index_count(), o.index_type(), 0, 0);
                const auto& a = *g.aabbs;
                g.aabbs = std::make_unique<fbs::GeometryAabbNV>(a.aabb_data(), uint32_t(rng()),
                                                                uint32_t(rng() % 64), a.offset());
            }
            auto obj = t.create(info, 1000);
            t.build(info, obj);
            std::vector<InstanceSpec> inst = random_instances(8, 1, 3.0f, rng());
            NvWorld side;
            auto bytes = side.instance_bytes(inst, {rng() % 2 ? obj.driver_handle : rng()});
            for (int k = 0, n = 1 + int(rng() % 10); k < n; ++k)
                bytes[rng() % bytes.size()] = uint8_t(rng());
            const uint64_t ib = t.buffer(bytes.data(), bytes.size());
            auto tinfo = NvTraceBuilder::tlas_info(rng() % 4 ? 8 : uint32_t(rng()));
            auto tlas = t.create(tinfo, 4000);
            t.build(tinfo, tlas, ib, rng() % 4 == 0, rng() % 2 ? &tlas : nullptr);
            t.submit();
            std::vector<eng::Ray> rays(50, eng::Ray{{0, 0, 9}, 0, {0.01f, 0.02f, -1}, 100});
            t.ray_check(tlas, rays, std::vector<uint32_t>(50, 0), std::vector<uint32_t>(50, 0xFF),
                        std::vector<RefHit>(50), "mutant");
            t.finish();
        }
        const replay::ReplayReport r = replay_file(path);
        EXPECT_GE(r.counts.records, 1u);
        EXPECT_EQ(r.ray_checks.size(), 1u);
    }
    std::filesystem::remove(path);
}

}  // namespace
}  // namespace clastrace::nvtest
