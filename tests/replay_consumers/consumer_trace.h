// SPDX-License-Identifier: Apache-2.0
// Hand-written traces of a ray-traced frame loop on VK_NV_ray_tracing objects, as the capture
// layer would write them: a pool of one-triangle bottom levels, a top level over them, rays
// (or ray queries) reading the top level, fences, presents ending frames.
#pragma once

#include <clastrace/trace_building/record_writer.h>
#include <vulkan/vulkan.h>

#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::consumertest {

inline constexpr uint64_t kBuildStages = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
inline constexpr uint64_t kRayStages = VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR;
inline constexpr uint64_t kStructureWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
inline constexpr uint64_t kStructureRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;

class ConsumerTrace {
public:
    explicit ConsumerTrace(const std::string& path);

    struct Object {
        uint64_t handle = 0;
        uint64_t driver_handle = 0;  // what instances name it by
    };
    Object bottom_level();                 // created and bound, not built
    Object top_level(uint32_t instances);  // created and bound, not built
    // A KHR structure in a buffer of its own; driver_handle holds its device address and
    // `buffer` the buffer.
    Object khr_structure(bool top_level, uint64_t* buffer = nullptr);
    // vkCmdBuildAccelerationStructuresKHR of a KHR top level over `blas` (their addresses),
    // packed or as an array of pointers. Not executed by this replay: only what it names counts.
    void build_khr_top(const Object& tlas, const std::vector<Object>& blas, bool array_of_pointers);
    // vkCmdFillBuffer over the whole buffer.
    void fill(uint64_t buffer);
    // vkCmdBuildAccelerationStructureNV of a one-triangle bottom level into `blas`.
    void build_bottom(const Object& blas);
    // vkCmdBuildAccelerationStructureNV of `tlas` over instances of `blas`, in order.
    void build_top(const Object& tlas, const std::vector<Object>& blas);
    void barrier(uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                 uint64_t dst_access);
    void trace_rays(const Object& tlas);
    void trace_rays_at(uint64_t address);  // bound by device address only
    void ray_query_dispatch(const Object& tlas);
    // A ray-query dispatch reaching `structures` as given (any source).
    void ray_query_dispatch(std::vector<fbs::AccelerationStructureBinding> structures);
    void ray_query_draw(const Object& tlas, uint64_t stages);
    // Ends the open command buffer; the next command opens another in the same submission.
    void next_command_buffer();
    // Commands from here go into a new secondary command buffer (level 1) until
    // end_secondary(), which returns its handle for execute_commands().
    void begin_secondary();
    uint64_t end_secondary();
    void execute_commands(std::vector<uint64_t> secondaries);
    // Ends the open command buffer and submits it, after those next_command_buffer() ended, in
    // one batch with `fence` (no wait).
    void submit(uint64_t fence);
    void wait(uint64_t fence);
    void present(uint64_t frame);
    // The PreRangeState record a frame range starts with (format 1.5): the next submission is
    // its prelude (`prelude_submission`, its QueueSubmit.submission_index).
    void pre_range_state(uint64_t before_frame, uint64_t prelude_submission);
    void destroy(const Object& o);
    void finish();

private:
    uint64_t buffer(const void* bytes, uint64_t size);  // bound; bytes go into the next inputs
    uint64_t open();
    Object create_nv(const fbs::AccelerationStructureInfoNVT& info);

    trace_building::RecordWriter writer_;
    std::vector<fbs::MemorySnapshot> inputs_;
    uint64_t next_buffer_ = 0x5000, next_address_ = 0x10000000, next_object_ = 0xA5000,
             next_object_offset_ = 0, command_buffer_ = 0xC000, next_secondary_ = 0xD000;
    uint64_t secondary_ = 0;       // the secondary being recorded; 0: none
    std::vector<uint64_t> ended_;  // primaries ended for the next submit
    uint64_t last_address_ = 0;    // of the buffer buffer() made last
    bool open_ = false;
};

}  // namespace clastrace::consumertest
