// What the layer knows of the NV acceleration structures an application built, from the bytes
// the capture read at each vkCmdBuildAccelerationStructureNV: per bottom level its geometries'
// kinds, boxes and bounds; per top level its instance records. The ray check (CLASTRACE_RAY_CHECK)
// turns that into the tables its hit shaders read and into rays aimed at the instances.
#pragma once

#include "clastrace/capture/capture_records.h"
#include "clastrace/capture/nv_ray_tracer.h"

#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace clastrace::capture {

struct NvGeometryModel {
  bool aabbs = false;
  std::vector<float> boxes;  // AABB geometries: 6 floats per box, in the build's order
  bool bounded = false;      // lo/hi hold the geometry's object-space bounds
  float lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
};

struct NvInstanceRecord {  // VkAccelerationStructureInstanceNV, unpacked
  float transform[12] = {};
  uint32_t customIndex = 0, mask = 0, sbtRecordOffset = 0, flags = 0;
  uint64_t reference = 0;  // the bottom level's handle from vkGetAccelerationStructureHandleNV
};

class NvSceneModel {
 public:
  void setHandle(uint64_t accelerationStructure, uint64_t deviceHandle);
  void forget(uint64_t accelerationStructure);
  // Records what the build read (the capture's input ranges for `command`).
  void observeBuild(const BuildAccelerationStructureNVCommand& command, const std::vector<CapturedRange>& inputs);
  // The hit-shader tables for `topLevel` and `rayCount` deterministic rays aimed at its
  // instances; false + `why` when the model cannot describe it (unknown bottom level, an SBT
  // record used by both triangles and boxes, too many records).
  bool prepare(uint64_t topLevel, uint32_t rayCount, NvTraceScene& scene, std::vector<NvTracedRay>& rays,
               uint64_t& deviceHandle, std::string& why) const;

 private:
  mutable std::mutex mutex_;
  std::map<uint64_t, std::vector<NvGeometryModel>> bottomLevels_;  // by VkAccelerationStructureNV
  std::map<uint64_t, std::vector<NvInstanceRecord>> topLevels_;
  std::map<uint64_t, uint64_t> byDeviceHandle_;  // device handle -> acceleration structure
  std::map<uint64_t, uint64_t> deviceHandles_;   // acceleration structure -> device handle
};

// Hit records beyond this are not modelled (an instance SBT offset is 24 bits).
constexpr uint32_t kMaxRayCheckHitRecords = 1u << 16;

}  // namespace clastrace::capture
