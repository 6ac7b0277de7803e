// SPDX-License-Identifier: Apache-2.0
// The trace sink's NV records (capture/src/trace_capture_sink.cpp): acceleration-structure
// objects go out once with their handle, followed by their requirements and binding; the
// header carries the driver identity; a ray check lands right after its submission, also when
// it arrives before that submission could be written.
#include "clastrace/capture/capture_sink.h"

#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <vector>

namespace clastrace::capture {
namespace {

std::string tempPath(const char* name) {
    return (std::filesystem::temp_directory_path() / (std::string("clastrace_") + name + ".clt"))
        .string();
}

DeviceRecord h100() {
    DeviceRecord d;
    d.device = 1;
    d.device_name = "NVIDIA H100 80GB HBM3";
    d.vendor_id = 0x10DE;
    d.driver_id = VK_DRIVER_ID_NVIDIA_PROPRIETARY;
    d.driver_name = "NVIDIA";
    d.driver_info = "580.159.04";
    for (uint8_t i = 0; i < 16; ++i) {
        d.driver_uuid.push_back(i);
        d.device_uuid.push_back(uint8_t(0xF0 + i));
    }
    d.has_ray_tracing_properties_nv = true;
    d.ray_tracing_properties_nv.shaderGroupHandleSize = 32;
    d.ray_tracing_properties_nv.maxInstanceCount = 16777215;
    return d;
}

std::vector<fbs::RecordBody> kinds(const std::string& path,
                                   std::unique_ptr<traces::TraceReader>& reader) {
    traces::TraceError error;
    reader = traces::TraceReader::open(path, &error);
    EXPECT_TRUE(reader) << error.message;
    std::vector<fbs::RecordBody> out;
    traces::RecordView view;
    while (reader && reader->next(&view)) out.push_back(view.kind);
    return out;
}

RayCheckRecord check(uint64_t submission) {
    RayCheckRecord c;
    c.acceleration_structure = 0x30;
    c.device_handle = 0xC000;
    c.submission_index = submission;
    c.label = "test";
    NvTracedRay ray{{1, 2, 3}, 0.5f, {0, 0, -1}, 100.0f, 0, 0xFF, {0, 0}};
    NvRayHit hit{1, 2.5f, 7, 1, 3, 0, 0xFE, 0.25f, 0.5f, {0, 0, 0}};
    c.rays = {ray, ray};
    c.hits = {hit, NvRayHit{}};
    return c;
}

TEST(TraceSinkNv, ObjectsCarryTheirHandleAndHeaderTheDriverIdentity) {
    const std::string path = tempPath("sink_nv_objects");
    {
        std::string error;
        auto sink = make_trace_capture_sink(path, 3, error);
        ASSERT_TRUE(sink) << error;
        sink->device_created(h100());
        AccelerationStructureRecord nv;
        nv.acceleration_structure = 0x10;
        nv.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
        nv.info_type = nv.type;
        nv.geometries.resize(2);
        sink->acceleration_structure_created(nv);
        sink->acceleration_structure_memory_requirements({0x10, 0, 4096, 256, 3});
        sink->acceleration_structure_bound({0x10, 0x99, 512});
        sink->acceleration_structure_address_queried({0x10, 0xABC000});
        sink->acceleration_structure_address_queried({0x10, 0xABC000});  // asked again: nothing new
        AccelerationStructureRecord khr;
        khr.acceleration_structure = 0x20;
        khr.khr = true;
        khr.buffer = 0x55;
        khr.size = 1408;
        sink->acceleration_structure_created(
            khr);  // never asked for its address: goes out at destroy
        sink->acceleration_structure_destroyed(0x20);
    }
    std::unique_ptr<traces::TraceReader> reader;
    const auto got = kinds(path, reader);
    using K = fbs::RecordBody;
    const std::vector<K> expected = {K::AccelerationStructureCreate,
                                     K::AccelerationStructureMemoryRequirementsNV,
                                     K::AccelerationStructureBindMemory,
                                     K::AccelerationStructureCreate,
                                     K::AccelerationStructureDestroy};
    EXPECT_EQ(got, expected);
    ASSERT_TRUE(reader && reader->header() && reader->header()->device());
    const fbs::DeviceInfo* d = reader->header()->device();
    EXPECT_EQ(d->driver_name()->str(), "NVIDIA");
    EXPECT_EQ(d->driver_id(), uint32_t(VK_DRIVER_ID_NVIDIA_PROPRIETARY));
    ASSERT_TRUE(d->driver_uuid() && d->device_uuid());
    EXPECT_EQ(d->driver_uuid()->size(), 16u);
    EXPECT_EQ(d->device_uuid()->Get(15), 0xFFu);
    ASSERT_TRUE(d->ray_tracing_properties_nv());
    EXPECT_EQ(d->ray_tracing_properties_nv()->shader_group_handle_size(), 32u);

    // The first create carries the NV handle and its geometry count.
    reader = traces::TraceReader::open(path, nullptr);
    traces::RecordView view;
    ASSERT_TRUE(reader && reader->next(&view));
    const auto* create = view.record->body_as_AccelerationStructureCreate();
    ASSERT_TRUE(create);
    EXPECT_EQ(create->device_address(), 0xABC000u);
    EXPECT_EQ(create->api(), 0u);
    ASSERT_TRUE(create->info() && create->info()->geometries());
    EXPECT_EQ(create->info()->geometries()->size(), 2u);
    std::remove(path.c_str());
}

TEST(TraceSinkNv, RayCheckFollowsItsSubmissionEvenWhenItArrivesFirst) {
    const std::string path = tempPath("sink_nv_ray_check");
    {
        std::string error;
        auto sink = make_trace_capture_sink(path, 3, error);
        ASSERT_TRUE(sink) << error;
        sink->device_created(h100());
        // Submission 7 holds one captured NV build; its capture arrives after the ray check.
        RecordedCommandBuffer cb;
        cb.command_buffer = 0x77;
        BuildAccelerationStructureNVCommand build;
        build.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
        build.dst = 0x30;
        build.pause_id = 1;
        cb.commands.push_back(build);
        sink->command_buffer_recorded(cb);
        SubmissionRecord s;
        s.index = 7;
        s.batches.push_back({{}, {0x77}, {}});
        sink->queue_submitted(s);
        sink->ray_query_checked(check(7));
        ClusterBuildCapture captured;
        captured.kind = CapturedCommandKind::kBuildAccelerationStructureNv;
        captured.pause_id = 1;
        captured.submission_index = 7;
        sink->cluster_build_captured(captured);
        // A later ray check of an already written submission goes out at once.
        sink->ray_query_checked(check(7));
    }
    std::unique_ptr<traces::TraceReader> reader;
    const auto got = kinds(path, reader);
    using K = fbs::RecordBody;
    const std::vector<K> expected = {K::CommandBufferBegin, K::CmdBuildAccelerationStructureNV,
                                     K::CommandBufferEnd,   K::QueueSubmit,
                                     K::RayQueryCheck,      K::RayQueryCheck};
    EXPECT_EQ(got, expected);
    reader = traces::TraceReader::open(path, nullptr);
    traces::RecordView view;
    uint64_t submission = ~0ull;
    while (reader->next(&view)) {
        if (view.kind == K::QueueSubmit)
            submission = view.record->body_as_QueueSubmit()->submission_index();
        if (view.kind != K::RayQueryCheck) continue;
        const auto* c = view.record->body_as_RayQueryCheck();
        EXPECT_EQ(c->after_submission(), submission);  // the trace's index, not the layer's 7
        EXPECT_EQ(c->device_handle(), 0xC000u);
        ASSERT_EQ(c->rays()->size(), 2u);
        ASSERT_EQ(c->results()->size(), 2u);
        EXPECT_EQ(c->rays()->Get(0)->t_min(), 0.5f);
        EXPECT_EQ(c->results()->Get(0)->instance_custom_index(), 7u);
        EXPECT_EQ(c->results()->Get(0)->hit_kind(), 0xFEu);
        EXPECT_EQ(c->results()->Get(1)->hit(), 0u);
        EXPECT_EQ(c->results()->Get(1)->geometry_index(), 0xFFFFFFFFu);  // a miss has none
    }
    std::remove(path.c_str());
}

}  // namespace
}  // namespace clastrace::capture
