// SPDX-License-Identifier: Apache-2.0
// A trace written command by command with the TraceWriter, as a capture would record it:
// buffers with their usage, cluster commands with their input snapshots, copies, fills,
// updates, dispatches, barriers, submissions with semaphores, host waits. No mirror
// engine: the replay computes every output itself (no captured outputs are written).
#pragma once

#include <clastrace/trace_building/cluster_structs.h>
#include <clastrace/engine/properties.h>
#include <clastrace/trace_building/record_writer.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace clastrace::test {

// Bytes a command's capture saw at `address` before it ran.
struct InputSnapshot {
    uint64_t address = 0;
    std::vector<uint8_t> bytes;
};

using trace_building::bytes_of;

struct SemaphoreUse {
    uint64_t semaphore = 0;
    uint64_t value = 0;  // 0: binary
    uint64_t stages = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;
};

struct ScriptDevice {
    uint32_t max_vertices_per_cluster = 16;
    uint32_t max_triangles_per_cluster = 16;
    uint32_t cluster_scratch_byte_alignment = 128;
    uint32_t cluster_byte_alignment = 128;
    uint32_t cluster_template_byte_alignment = 32;
    uint32_t cluster_bottom_level_byte_alignment = 256;
    uint32_t cluster_template_bounds_byte_alignment = 32;
    uint32_t max_cluster_geometry_index = 1000;
    // The trace's driverName: null names the engine (an engine trace); anything else makes it
    // a driver trace, whose sizes replay compares rather than checks.
    const char* driver_name = nullptr;
};

class TraceScript {
public:
    TraceScript(const std::string& path, const ScriptDevice& device = {});
    ~TraceScript();

    // --- memory ---------------------------------------------------------------------
    // A buffer bound to `memory` at `memory_offset` with device address `address` (0: none).
    void buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage,
                uint64_t memory = 0x1001, uint64_t memory_offset = 0);
    // A buffer created with VK_BUFFER_CREATE_SPARSE_BINDING_BIT: no memory until bind_sparse.
    void sparse_buffer(uint64_t handle, uint64_t size, uint64_t usage);
    // vkGetClusterAccelerationStructureBuildSizesNV with this input (10445), answered as the
    // engine answers it on this device.
    void query_build_sizes(const VkClusterAccelerationStructureInputInfoNV& input);
    // The same query answered with a driver's own sizes.
    void query_build_sizes(const VkClusterAccelerationStructureInputInfoNV& input,
                           uint64_t acceleration_structure_size, uint64_t build_scratch_size);
    // vkCreateAccelerationStructureKHR over [offset, offset + size) of `buffer`.
    void acceleration_structure(
        uint64_t handle, uint64_t buffer, uint64_t offset, uint64_t size,
        VkAccelerationStructureTypeKHR type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    // Host write to mapped memory observed between submissions.
    void host_write(uint64_t address, const std::vector<uint8_t>& bytes);

    // --- commands of the current command buffer ---------------------------------------
    // `driver_bvh`: ranges the capture marked as a traceable cluster BLAS's driver BVH.
    void cluster(const VkClusterAccelerationStructureCommandsInfoNV& info,
                 const std::vector<InputSnapshot>& inputs,
                 const std::vector<fbs::DeviceAddressRange>& driver_bvh = {});
    void copy(uint64_t src_buffer, uint64_t src_offset, uint64_t dst_buffer, uint64_t dst_offset,
              uint64_t size, const std::vector<InputSnapshot>& inputs = {});
    void fill(uint64_t dst_buffer, uint64_t offset, uint64_t size, uint32_t data);
    // vkCmdCopyMemoryToAccelerationStructureKHR (deserialize) of `serialized` at src_address.
    void deserialize(uint64_t src_address, uint64_t dst_object,
                     const std::vector<uint8_t>& serialized);
    void update(uint64_t dst_buffer, uint64_t offset, const std::vector<uint8_t>& data);
    // A dispatch with one storage buffer range bound; `outputs` is what the capture saw it write.
    void dispatch(uint64_t storage_buffer, uint64_t offset, uint64_t range,
                  const std::vector<InputSnapshot>& outputs = {});
    // A dispatch with no storage buffer whose pipeline may write through buffer device
    // addresses (CmdDispatch.may_write_device_addresses); `outputs` as above.
    void dispatch_through_addresses(const std::vector<InputSnapshot>& outputs = {});
    // A draw (CmdDraw, `entry_point` such as "vkCmdDrawMeshTasksEXT") whose shaders at `stages`
    // (VkPipelineStageFlags2) may write through buffer device addresses.
    void draw_through_addresses(const std::string& entry_point, uint64_t stages);
    // CLASTRACE_DEVICE_ADDRESS_WRITES=exact: what the previous command (a dispatch) changed in
    // this execution, as a DeviceAddressWrites record written, as the capture does, just before
    // the QueueSubmit that runs the command buffer.
    void exact_address_writes(const std::vector<InputSnapshot>& writes);
    void barrier(uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                 uint64_t dst_access);
    // vkCmdPipelineBarrier (synchronization 1) with one VkMemoryBarrier.
    void barrier_v1(uint32_t src_stages, uint32_t src_access, uint32_t dst_stages,
                    uint32_t dst_access);
    void buffer_barrier(uint64_t buffer, uint64_t offset, uint64_t size, uint64_t src_stages,
                        uint64_t src_access, uint64_t dst_stages, uint64_t dst_access);
    // vkCmdSetEvent2 / vkCmdWaitEvents2 with one VkMemoryBarrier2.
    void set_event(uint64_t event, uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                   uint64_t dst_access);
    void wait_event(uint64_t event, uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                    uint64_t dst_access);
    // ALL_COMMANDS/MEMORY_WRITE -> ALL_COMMANDS/MEMORY_READ|WRITE.
    void full_barrier();
    // A command record the caller built (its body names command_buffer()), appended to the
    // current command buffer: records this script has no method for (tests/replay_consumers).
    void command(const fbs::RecordT& record);

    // --- queues ---------------------------------------------------------------------
    // Ends the current command buffer and submits it (version 1: vkQueueSubmit, whose
    // signals carry no stage mask; 2: vkQueueSubmit2). Later commands go into a fresh one.
    void submit(uint64_t queue, const std::vector<SemaphoreUse>& waits = {},
                const std::vector<SemaphoreUse>& signals = {}, uint64_t fence = 0,
                uint8_t version = 2);
    // Ends the current command buffer; the next commands go into a fresh one, submitted in
    // the same batch as this one by the next submit().
    void next_command_buffer();
    // Submits an already recorded command buffer again (or one that was reset).
    void resubmit(uint64_t queue, uint64_t command_buffer, uint64_t fence = 0);
    // vkQueueBindSparse of one batch binding `binds` under the sparse buffer `buffer`, whose
    // device address is `address`; signals `signal` (binary, 0: none).
    void bind_sparse(uint64_t queue, uint64_t buffer, uint64_t address,
                     const std::vector<VkSparseMemoryBind>& binds, uint64_t signal = 0);
    void wait_fence(uint64_t fence);
    void device_wait_idle();
    // Format 1.2: vkQueuePresentKHR waiting on binary `waits`, and vkAcquireNextImageKHR
    // signalling `semaphore` and `fence` (0: none) with `result` (`device_mask` not 0:
    // vkAcquireNextImage2KHR).
    void present(uint64_t queue, const std::vector<uint64_t>& waits, uint64_t frame = 0);
    void acquire(uint64_t semaphore, uint64_t fence = 0, int32_t result = 0,
                 uint32_t device_mask = 0);
    // vkResetCommandBuffer (pool 0) or, with command_buffer 0, vkResetCommandPool.
    void reset(uint64_t command_buffer, uint64_t pool);
    // The command buffer commands go into now (begun on first use).
    uint64_t command_buffer() const { return command_buffer_; }
    // Index the next command gets within the current command buffer.
    uint32_t next_command() const { return begun_ ? commands_ : 0; }
    // Starts recording a given command buffer (e.g. to re-record one); flags as vkBeginCommandBuffer.
    void begin(uint64_t command_buffer, uint32_t flags = 0);
    // Format 1.2: begins `command_buffer` as a secondary (level 1) and/or as restatement k of
    // its recording (the (k+1)-th execution in the next submission, CommandBufferBegin.restatement).
    void begin(uint64_t command_buffer, uint32_t flags, uint32_t level, uint32_t restatement);
    // Ends the current command buffer without queueing it for a submit (a secondary, a restatement).
    void end();
    // vkCmdExecuteCommands in the current command buffer.
    void execute_commands(const std::vector<uint64_t>& secondaries);
    // One vkQueueSubmit of one batch listing `command_buffers` (already recorded), in this order.
    void submit_listed(uint64_t queue, const std::vector<uint64_t>& command_buffers,
                       uint64_t fence = 0);

    // Submits what is recorded (if anything), waits for the device, finishes the file.
    void finish();

private:
    void ensure_begun();
    trace_building::RecordWriter writer_;
    engine::EngineProperties properties_;  // the device the header describes
    uint64_t command_buffer_ = 0xc000;
    uint64_t next_command_buffer_ = 0xc001;
    bool begun_ = false;
    bool recorded_ = false;
    uint32_t commands_ = 0;
    std::vector<uint64_t> batch_;  // ended command buffers waiting for the next submit()
    std::vector<fbs::DeviceAddressWritesT> exact_writes_;  // for the next submit()
};

}  // namespace clastrace::test
