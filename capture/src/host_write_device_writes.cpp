// SPDX-License-Identifier: Apache-2.0
#include "host_write_device_writes.h"

#include "command_buffer_log.h"
#include "layer_state.h"

#include "clastrace/capture/layer_config.h"

#include <algorithm>
#include <memory>
#include <string>
#include <variant>

namespace clastrace::capture {
namespace {

// Secondaries executing secondaries is not valid Vulkan; the bound keeps a bad log finite.
constexpr int kMaxExecuteDepth = 4;

class WriteCollector {
public:
    explicit WriteCollector(DeviceState& d) : d_(d) {}

    void add_command_buffer(uint64_t id, int depth) {
        if (depth > kMaxExecuteDepth) return;
        std::shared_ptr<CommandBufferLog> log;
        {
            std::lock_guard lock(d_.command_buffers_mutex);
            auto it = d_.command_buffers.find(reinterpret_cast<VkCommandBuffer>(id));
            if (it == d_.command_buffers.end()) return;
            log = it->second;
        }
        for (const RecordedCommand& c : log->recorded.commands) add_command(c, depth);
    }

    std::vector<MemorySpan> spans;

private:
    void add_command(const RecordedCommand& command, int depth) {
        if (const auto* c = std::get_if<CopyBufferCommand>(&command)) {
            for (const VkBufferCopy& r : c->regions) add_buffer(c->dst, r.dstOffset, r.size);
        } else if (const auto* f = std::get_if<FillBufferCommand>(&command)) {
            add_buffer(f->dst, f->offset, f->size);
        } else if (const auto* u = std::get_if<UpdateBufferCommand>(&command)) {
            add_buffer(u->dst, u->offset, u->data.size());
        } else if (const auto* dispatch = std::get_if<DispatchCommand>(&command)) {
            // The layer does not know which bound storage buffers a shader writes: all may be.
            for (const BoundStorageBuffer& b : dispatch->storage_buffers)
                add_buffer(b.buffer, b.offset, b.range);
            // With CLASTRACE_DEVICE_ADDRESS_WRITES=off no shader is scanned: any dispatch may
            // write through an address, so none of its submission's changes is claimed.
            if (dispatch->may_write_device_addresses || !layer_config().mark_device_address_writers)
                add_any_memory();
        } else if (const auto* draw = std::get_if<DrawCommand>(&command)) {
            // Draws are kept when their pipeline may write through addresses or uses ray queries.
            if (draw->address_stages || !layer_config().mark_device_address_writers)
                add_any_memory();
        } else if (const auto* rays = std::get_if<TraceRaysCommand>(&command)) {
            for (const BoundStorageBuffer& b : rays->storage_buffers)
                add_buffer(b.buffer, b.offset, b.range);
            if (rays->may_write_device_addresses || !layer_config().mark_device_address_writers)
                add_any_memory();
        } else if (const auto* build = std::get_if<ClusterBuildCommand>(&command)) {
            const VkClusterAccelerationStructureCommandsInfoNV& info = build->parameters.info;
            for (VkDeviceAddress a :
                 {info.dstImplicitData, info.scratchData, info.dstAddressesArray.deviceAddress,
                  info.dstSizesArray.deviceAddress})
                add_address_to_buffer_end(a);
        } else if (const auto* nv = std::get_if<BuildAccelerationStructureNVCommand>(&command)) {
            add_buffer(nv->scratch, nv->scratch_offset, VK_WHOLE_SIZE);
        } else if (const auto* khr = std::get_if<BuildAccelerationStructuresKHRCommand>(&command)) {
            for (const KhrBuildInfo& info : khr->infos) {
                add_address_to_buffer_end(info.info.scratchData.deviceAddress);
                add_structure(uint64_t(info.info.dstAccelerationStructure));
            }
        } else if (const auto* copy = std::get_if<CopyAccelerationStructureCommand>(&command)) {
            if (copy->to_memory)
                add_address_to_buffer_end(copy->dst_address);
            else if (copy->khr)
                add_structure(copy->dst);
        } else if (const auto* execute = std::get_if<ExecuteCommandsCommand>(&command)) {
            for (uint64_t secondary : execute->secondaries)
                add_command_buffer(secondary, depth + 1);
        }
    }

    // A KHR structure's storage in its buffer (NV structures own memory the layer cannot map).
    void add_structure(uint64_t acceleration_structure) {
        const KhrStructureStorage s = khr_structure_storage(d_, acceleration_structure);
        if (s.buffer) add_buffer(s.buffer, s.offset, s.size);
    }

    void add_any_memory() { spans.push_back({MemorySpan::kAnyMemory, 0, ~VkDeviceSize{0}}); }

    // VK_WHOLE_SIZE (or a size past the buffer) runs to the buffer's end.
    void add_buffer(uint64_t handle, VkDeviceSize offset, VkDeviceSize size) {
        std::optional<TrackedBuffer> b = d_.memory_map.buffer(handle);
        if (!b || !b->memory || offset >= b->size) return;
        const VkDeviceSize end = size > b->size - offset ? b->size : offset + size;
        spans.push_back({b->memory, b->memory_offset + offset, b->memory_offset + end});
    }

    void add_address_to_buffer_end(VkDeviceAddress address) {
        if (!address) return;
        std::string why;
        std::optional<ResolvedRange> r = d_.memory_map.resolve(address, 1, why);
        if (!r) return;  // not in a buffer the layer knows: no mapped input can be there either
        add_buffer(r->buffer.handle, r->offset_in_buffer, VK_WHOLE_SIZE);
    }

    DeviceState& d_;
};

}  // namespace

std::vector<MemorySpan> device_writes_of(DeviceState& d,
                                         const std::vector<uint64_t>& command_buffers) {
    WriteCollector collector(d);
    for (uint64_t cb : command_buffers) collector.add_command_buffer(cb, 0);
    return std::move(collector.spans);
}

bool overlaps_any(const std::vector<MemorySpan>& spans, const MemorySpan& span) {
    return std::any_of(spans.begin(), spans.end(),
                       [&](const MemorySpan& s) { return s.overlaps(span); });
}

}  // namespace clastrace::capture
