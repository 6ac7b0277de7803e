// SPDX-License-Identifier: Apache-2.0
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
    uint32_t custom_index = 0, mask = 0, sbt_record_offset = 0, flags = 0;
    uint64_t reference = 0;  // the bottom level's handle from vkGetAccelerationStructureHandleNV
};

class NvSceneModel {
public:
    void set_handle(uint64_t acceleration_structure, uint64_t device_handle);
    void forget(uint64_t acceleration_structure);
    // Records what the build read (the capture's input ranges for `command`).
    void observe_build(const BuildAccelerationStructureNVCommand& command,
                       const std::vector<CapturedRange>& inputs);
    // The hit-shader tables for `topLevel` and `rayCount` deterministic rays aimed at its
    // instances; false + `why` when the model cannot describe it (unknown bottom level, an SBT
    // record used by both triangles and boxes, too many records).
    bool prepare(uint64_t top_level, uint32_t ray_count, NvTraceScene& scene,
                 std::vector<NvTracedRay>& rays, uint64_t& device_handle, std::string& why) const;

private:
    mutable std::mutex mutex_;
    std::map<uint64_t, std::vector<NvGeometryModel>>
        bottom_levels_;  // by VkAccelerationStructureNV
    std::map<uint64_t, std::vector<NvInstanceRecord>> top_levels_;
    std::map<uint64_t, uint64_t> by_device_handle_;  // device handle -> acceleration structure
    std::map<uint64_t, uint64_t> device_handles_;    // acceleration structure -> device handle
};

// Hit records beyond this are not modelled (an instance SBT offset is 24 bits).
constexpr uint32_t kMaxRayCheckHitRecords = 1u << 16;

}  // namespace clastrace::capture
