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
  return (std::filesystem::temp_directory_path() / (std::string("clastrace_") + name + ".clt")).string();
}

DeviceRecord h100() {
  DeviceRecord d;
  d.device = 1;
  d.deviceName = "NVIDIA H100 80GB HBM3";
  d.vendorId = 0x10DE;
  d.driverId = VK_DRIVER_ID_NVIDIA_PROPRIETARY;
  d.driverName = "NVIDIA";
  d.driverInfo = "580.159.04";
  for (uint8_t i = 0; i < 16; ++i) {
    d.driverUuid.push_back(i);
    d.deviceUuid.push_back(uint8_t(0xF0 + i));
  }
  d.hasRayTracingPropertiesNV = true;
  d.rayTracingPropertiesNV.shaderGroupHandleSize = 32;
  d.rayTracingPropertiesNV.maxInstanceCount = 16777215;
  return d;
}

std::vector<fbs::RecordBody> kinds(const std::string& path, std::unique_ptr<traces::TraceReader>& reader) {
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
  c.accelerationStructure = 0x30;
  c.deviceHandle = 0xC000;
  c.submissionIndex = submission;
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
    auto sink = makeTraceCaptureSink(path, 3, error);
    ASSERT_TRUE(sink) << error;
    sink->deviceCreated(h100());
    AccelerationStructureRecord nv;
    nv.accelerationStructure = 0x10;
    nv.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    nv.infoType = nv.type;
    nv.geometries.resize(2);
    sink->accelerationStructureCreated(nv);
    sink->accelerationStructureMemoryRequirements({0x10, 0, 4096, 256, 3});
    sink->accelerationStructureBound({0x10, 0x99, 512});
    sink->accelerationStructureAddressQueried({0x10, 0xABC000});
    sink->accelerationStructureAddressQueried({0x10, 0xABC000});  // asked again: nothing new
    AccelerationStructureRecord khr;
    khr.accelerationStructure = 0x20;
    khr.khr = true;
    khr.buffer = 0x55;
    khr.size = 1408;
    sink->accelerationStructureCreated(khr);  // never asked for its address: goes out at destroy
    sink->accelerationStructureDestroyed(0x20);
  }
  std::unique_ptr<traces::TraceReader> reader;
  const auto got = kinds(path, reader);
  using K = fbs::RecordBody;
  const std::vector<K> expected = {K::AccelerationStructureCreate, K::AccelerationStructureMemoryRequirementsNV,
                                   K::AccelerationStructureBindMemory, K::AccelerationStructureCreate,
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
    auto sink = makeTraceCaptureSink(path, 3, error);
    ASSERT_TRUE(sink) << error;
    sink->deviceCreated(h100());
    // Submission 7 holds one captured NV build; its capture arrives after the ray check.
    RecordedCommandBuffer cb;
    cb.commandBuffer = 0x77;
    BuildAccelerationStructureNVCommand build;
    build.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    build.dst = 0x30;
    build.pauseId = 1;
    cb.commands.push_back(build);
    sink->commandBufferRecorded(cb);
    SubmissionRecord s;
    s.index = 7;
    s.batches.push_back({{}, {0x77}, {}});
    sink->queueSubmitted(s);
    sink->rayQueryChecked(check(7));
    ClusterBuildCapture captured;
    captured.kind = CapturedCommandKind::BuildAccelerationStructureNV;
    captured.pauseId = 1;
    captured.submissionIndex = 7;
    sink->clusterBuildCaptured(captured);
    // A later ray check of an already written submission goes out at once.
    sink->rayQueryChecked(check(7));
  }
  std::unique_ptr<traces::TraceReader> reader;
  const auto got = kinds(path, reader);
  using K = fbs::RecordBody;
  const std::vector<K> expected = {K::CommandBufferBegin, K::CmdBuildAccelerationStructureNV, K::CommandBufferEnd,
                                   K::QueueSubmit, K::RayQueryCheck, K::RayQueryCheck};
  EXPECT_EQ(got, expected);
  reader = traces::TraceReader::open(path, nullptr);
  traces::RecordView view;
  uint64_t submission = ~0ull;
  while (reader->next(&view)) {
    if (view.kind == K::QueueSubmit) submission = view.record->body_as_QueueSubmit()->submission_index();
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
