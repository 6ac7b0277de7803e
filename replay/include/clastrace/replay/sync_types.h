// SPDX-License-Identifier: Apache-2.0
// The vocabulary the synchronization model is fed with: commands, accesses, barriers,
// submissions. Replay produces these from a trace and from the engine's execution record;
// nothing here depends on either.
#pragma once

#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

#include "clastrace/replay/sync_masks.h"

namespace clastrace::replay {

// Half-open device address range [begin, end).
struct AddressRange {
    uint64_t begin = 0;
    uint64_t end = 0;
    bool empty() const { return end <= begin; }
    bool overlaps(const AddressRange& o) const { return begin < o.end && o.begin < end; }
    friend bool operator==(const AddressRange&, const AddressRange&) = default;
};

// One part of an access's range as memory sees it (SyncModel::set_address_resolver).
struct ResolvedRange {
    AddressRange range;  // in memory's address space when bound; the range as given when not
    bool bound = true;
};

// Maps device addresses to the memory under them where that memory is not simply at the
// address: a sparse buffer's pages are bound to memory objects (vkQueueBindSparse) that other
// buffers may alias, so two accesses meet when they reach the same memory, whatever address
// each went through.
class AddressResolver {
public:
    virtual ~AddressResolver() = default;
    // False when `range` is the address of its own memory (nothing to resolve); otherwise
    // `parts` gets the parts of `range` in order, each resolved or marked unbound.
    virtual bool resolve(AddressRange range, std::vector<ResolvedRange>* parts) = 0;
};

using QueueId = uint32_t;
// Host accesses (mapped memory) live on their own timeline.
inline constexpr QueueId kHostQueue = 0xFFFFu;

// Where a command sits in the captured stream. `name` must outlive the model (string literal).
struct CommandRef {
    uint32_t submission = 0;      // index of the vkQueueSubmit(2) batch in the trace
    uint32_t command_buffer = 0;  // index of the command buffer within that submission
    uint64_t command_buffer_handle = 0;
    uint32_t command = 0;   // index of the command within its command buffer
    const char* name = "";  // e.g. "vkCmdBuildClusterAccelerationStructureIndirectNV"
    // A command of a secondary command buffer: `command` is the primary's vkCmdExecuteCommands,
    // `secondary` the position in its list, `secondary_command` the index within the secondary.
    uint64_t secondary_handle = 0;  // 0: a command of the primary itself
    uint32_t secondary = 0;
    uint32_t secondary_command = 0;
    friend bool operator==(const CommandRef& a, const CommandRef& b) {
        return a.submission == b.submission && a.command_buffer == b.command_buffer &&
               a.command == b.command && a.command_buffer_handle == b.command_buffer_handle &&
               a.secondary_handle == b.secondary_handle && a.secondary == b.secondary &&
               a.secondary_command == b.secondary_command;
    }
};

// What a command does to a byte range. `stage` is one pipeline stage; `access` the access
// bits it performs there (e.g. ACCELERATION_STRUCTURE_READ|WRITE for scratch).
struct Access {
    AddressRange range;
    StageMask stage = 0;
    AccessMask access = 0;
    bool is_write = false;
    std::string_view field;  // which field of which info, e.g. "srcInfosArray[2]"; copied
    // An access the trace cannot pin down, only allow: a dispatch whose shader may write through
    // device addresses. Hazards with it on either side are reported as possible.
    bool possible = false;
};

// One memory dependency of a barrier (VkMemoryBarrier2, or a v1 barrier with the
// command's stage masks; an execution-only v1 barrier has zero access masks).
struct MemoryBarrier {
    StageMask src_stages = 0;
    AccessMask src_access = 0;
    StageMask dst_stages = 0;
    AccessMask dst_access = 0;
};

// VkBufferMemoryBarrier2 with its buffer/offset/size resolved to device addresses.
struct BufferBarrier {
    MemoryBarrier masks;
    AddressRange range;
};

// VkDependencyInfo (or a v1 barrier converted by the helpers below).
struct DependencyInfo {
    std::span<const MemoryBarrier> memory_barriers;
    std::span<const BufferBarrier> buffer_barriers;
    uint32_t dependency_flags = 0;
};

// v1 conversion: the command's stage masks go into every barrier.
inline MemoryBarrier memory_barrier_v1(VkPipelineStageFlags src_stages, VkAccessFlags src_access,
                                       VkPipelineStageFlags dst_stages, VkAccessFlags dst_access) {
    return {stages_from_v1(src_stages), accesses_from_v1(src_access), stages_from_v1(dst_stages),
            accesses_from_v1(dst_access)};
}
// A v1 vkCmdPipelineBarrier without memory barriers still is an execution dependency.
inline MemoryBarrier execution_barrier_v1(VkPipelineStageFlags src_stages,
                                          VkPipelineStageFlags dst_stages) {
    return memory_barrier_v1(src_stages, 0, dst_stages, 0);
}

struct SemaphoreWait {
    uint64_t semaphore = 0;
    uint64_t value = 0;  // timeline value; ignored for binary semaphores
    StageMask dst_stages = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;  // pWaitDstStageMask / stageMask
};
struct SemaphoreSignal {
    uint64_t semaphore = 0;
    uint64_t value = 0;  // timeline value; ignored for binary semaphores
    // VkSemaphoreSubmitInfo::stageMask: limits the signal's first synchronization scope.
    // vkQueueSubmit (v1) signals have none: the spec makes them ALL_COMMANDS.
    StageMask src_stages = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;
};

}  // namespace clastrace::replay
