// SPDX-License-Identifier: Apache-2.0
// Writes traces of VK_NV_ray_tracing programs with TraceWriter, as the capture layer on a
// driver would: buffers with device addresses, NV objects with driver handles and
// requirements, builds with input snapshots, deserializations, and RayQueryCheck records
// whose "driver" answers come from Embree.
#pragma once

#include "nv_scene.h"

#include <clastrace/trace_building/record_writer.h>

#include <memory>
#include <string>
#include <vector>

namespace clastrace::nvtest {

class NvTraceBuilder {
public:
    // max_instance_count != 0: the device reports VkPhysicalDeviceRayTracingPropertiesNV with it.
    NvTraceBuilder(const std::string& path, bool engine_device, uint64_t max_instance_count = 0,
                   std::vector<std::string> enabled_extensions = {});
    ~NvTraceBuilder();

    // A bound buffer holding `bytes` (snapshotted into the next command's inputs).
    uint64_t buffer(const void* bytes, uint64_t size,
                    uint64_t usage = VK_BUFFER_USAGE_RAY_TRACING_BIT_NV);
    struct Object {
        uint64_t handle = 0;
        uint64_t driver_handle = 0;
    };
    // vkCreateAccelerationStructureNV + requirements (driver sizes) + bind.
    Object create(const fbs::AccelerationStructureInfoNVT& info, uint64_t driver_object_size,
                  bool bind = true);
    // The BLAS of `spec` with its inputs in new buffers; returns the info used.
    fbs::AccelerationStructureInfoNVT blas_info(const BlasSpec& spec, uint32_t flags = 0);
    static fbs::AccelerationStructureInfoNVT tlas_info(uint32_t instance_count, uint32_t flags = 0);
    void build(const fbs::AccelerationStructureInfoNVT& info, const Object& dst,
               uint64_t instance_buffer = 0, bool update = false, const Object* src = nullptr,
               uint64_t scratch_size = 1 << 20,
               uint64_t scratch_buffer = 0);  // 0: a new scratch buffer
    void deserialize(uint64_t src_buffer, const Object& dst,
                     uint32_t mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR,
                     uint64_t src_offset = 0);
    void barrier();
    void submit();  // ends the command buffer, submits, waits on its fence
    void ray_check(const Object& tlas, const std::vector<eng::Ray>& rays,
                   const std::vector<uint32_t>& flags, const std::vector<uint32_t>& masks,
                   const std::vector<RefHit>& answers, const std::string& label);
    uint64_t address_of(uint64_t buffer) const;
    void finish();

private:
    void begin_if_needed();
    trace_building::RecordWriter writer_;
    std::vector<fbs::MemorySnapshot> pending_inputs_;
    std::vector<std::pair<uint64_t, uint64_t>> buffers_;  // handle, address
    uint64_t next_buffer_ = 0x5000, next_address_ = 0x10000000, next_object_ = 0xA5000,
             next_offset_ = 0;
    uint64_t command_buffer_ = 0xC0DE;
    bool open_ = false;
};

}  // namespace clastrace::nvtest
