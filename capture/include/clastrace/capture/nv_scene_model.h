// SPDX-License-Identifier: Apache-2.0
// What the layer knows of the NV and KHR acceleration structures an application built, from the
// bytes the capture read at each vkCmdBuildAccelerationStructureNV and each info of a
// vkCmdBuildAccelerationStructures(Indirect)KHR: per bottom level its geometries' kinds, boxes
// and bounds; per top level its instance records (the NV and KHR instance layouts are the same
// 64 bytes; the reference is an NV handle or a KHR device address, both registered with
// set_handle). The ray check (CLASTRACE_RAY_CHECK) turns that into the tables its shaders read
// and into rays aimed at the instances.
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
    // The bottom level's handle from vkGetAccelerationStructureHandleNV, or its
    // vkGetAccelerationStructureDeviceAddressKHR address.
    uint64_t reference = 0;
};

class NvSceneModel {
public:
    void set_handle(uint64_t acceleration_structure, uint64_t device_handle);
    void forget(uint64_t acceleration_structure);
    // Records what the build read (the capture's input ranges for `command`).
    void observe_build(const BuildAccelerationStructureNVCommand& command,
                       const std::vector<CapturedRange>& inputs);
    // Records what each info of a KHR build read. `indirect_ranges` holds an indirect build's
    // ranges as read at execution (one row per info; empty for a direct build).
    void observe_khr_build(
        const BuildAccelerationStructuresKHRCommand& command,
        const std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>>& indirect_ranges,
        const std::vector<CapturedRange>& inputs);
    // A served cluster BLAS the driver can traverse (capture/README.md "Traceable cluster
    // BLASes"): a KHR BLAS at `address` with one triangle geometry per cluster reference,
    // `triangles[g]` its 9 floats per triangle (NaN: inactive) and `geometry_indices[g]` each
    // triangle's geometry index in the cluster (the extension's gl_GeometryIndexEXT).
    void observe_cluster_blas(uint64_t address, const std::vector<std::vector<float>>& triangles,
                              std::vector<std::vector<uint32_t>> geometry_indices);
    // The driver reports a cluster BLAS's reference index as the geometry index: hits on an
    // instance of `top_level` that names one get the extension's (the triangle's geometry
    // index), or 0xFFFFFFFF where the model does not know it.
    void to_cluster_geometry_indices(uint64_t top_level, std::vector<NvRayHit>& hits) const;
    // Whether `top_level`'s last observed build was a KHR one (traced with the ray-query shader).
    bool is_khr_top_level(uint64_t top_level) const;
    // The hit-shader tables for `topLevel` and `rayCount` deterministic rays aimed at its
    // instances; false + `why` when the model cannot describe it (unknown bottom level, an SBT
    // record used by both triangles and boxes, too many records).
    bool prepare(uint64_t top_level, uint32_t ray_count, NvTraceScene& scene,
                 std::vector<NvTracedRay>& rays, uint64_t& device_handle, std::string& why) const;

private:
    // The geometries of the bottom level an instance reference names (a structure's handle or
    // address, or a traceable cluster BLAS's address); null when unknown. Under mutex_.
    const std::vector<NvGeometryModel>* bottom_level_of(uint64_t reference) const;

    mutable std::mutex mutex_;
    std::map<uint64_t, std::vector<NvGeometryModel>>
        bottom_levels_;  // by VkAccelerationStructureNV
    std::map<uint64_t, std::vector<NvInstanceRecord>> top_levels_;
    struct ClusterBlasModel {
        std::vector<NvGeometryModel> geometries;              // one per cluster reference
        std::vector<std::vector<uint32_t>> geometry_indices;  // [reference][triangle]
    };
    std::map<uint64_t, ClusterBlasModel> cluster_blases_;  // by device address
    std::map<uint64_t, bool> khr_top_levels_;              // top level -> built by a KHR build
    std::map<uint64_t, uint64_t> by_device_handle_;  // device handle -> acceleration structure
    std::map<uint64_t, uint64_t> device_handles_;    // acceleration structure -> device handle
};

// Hit records beyond this are not modelled (an instance SBT offset is 24 bits).
constexpr uint32_t kMaxRayCheckHitRecords = 1u << 16;

}  // namespace clastrace::capture
