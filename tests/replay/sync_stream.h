// SPDX-License-Identifier: Apache-2.0
// A small builder for the streams the synchronization tests feed to SyncModel.
#pragma once

#include <initializer_list>
#include <vector>

#include "clastrace/replay/sync_model.h"

namespace clastrace::replay::test {

inline constexpr StageMask kAsBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
inline constexpr StageMask kCopy = VK_PIPELINE_STAGE_2_COPY_BIT;
inline constexpr StageMask kClear = VK_PIPELINE_STAGE_2_CLEAR_BIT;
inline constexpr StageMask kCompute = VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT;
inline constexpr AccessMask kAsRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
inline constexpr AccessMask kAsWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
inline constexpr AccessMask kIndirect = VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT;
inline constexpr AccessMask kTransferWrite = VK_ACCESS_2_TRANSFER_WRITE_BIT;
inline constexpr AccessMask kTransferRead = VK_ACCESS_2_TRANSFER_READ_BIT;

inline constexpr const char* kBuildName = "vkCmdBuildClusterAccelerationStructureIndirectNV";

struct Stream {
    SyncModel model;
    uint32_t submission = 0;
    uint32_t command = 0;
    uint32_t command_buffer = 0;

    explicit Stream(SyncOptions options = {}) : model(options) {}

    void submit(QueueId queue = 0, std::initializer_list<SemaphoreWait> waits = {}) {
        model.begin_submission(queue, submission, std::vector<SemaphoreWait>(waits));
        command = 0;
        command_buffer = 0;
    }
    void end(std::initializer_list<SemaphoreSignal> signals = {}, uint64_t fence = 0) {
        model.end_submission(std::vector<SemaphoreSignal>(signals), fence);
        ++submission;
    }
    void next_command_buffer() {
        ++command_buffer;
        command = 0;
    }
    CommandRef next(const char* name) {
        return {submission, command_buffer, 0xC0 + command_buffer, command++, name};
    }

    static Access read(uint64_t begin, uint64_t end, StageMask stage, AccessMask access,
                       const char* field) {
        return {{begin, end}, stage, access, false, field};
    }
    static Access write(uint64_t begin, uint64_t end, StageMask stage, AccessMask access,
                        const char* field) {
        return {{begin, end}, stage, access, true, field};
    }

    // One cluster build command: reads its infos and count, uses scratch, writes its outputs.
    struct Build {
        AddressRange src_infos{}, src_count{}, scratch{}, dst_implicit{}, dst_addresses{},
            dst_sizes{};
        std::vector<std::pair<AddressRange, const char*>>
            inputs;  // e.g. CLAS references, vertex data
    };
    CommandRef build(const Build& b) {
        const CommandRef c = next(kBuildName);
        if (!b.src_infos.empty())
            model.record_access(c, read(b.src_infos.begin, b.src_infos.end, kAsBuild, kIndirect,
                                        "srcInfosArray"));
        if (!b.src_count.empty())
            model.record_access(c, read(b.src_count.begin, b.src_count.end, kAsBuild, kIndirect,
                                        "srcInfosCount"));
        for (const auto& [range, field] : b.inputs)
            model.record_access(c, read(range.begin, range.end, kAsBuild, kAsRead, field));
        if (!b.scratch.empty())
            model.record_access(c, write(b.scratch.begin, b.scratch.end, kAsBuild,
                                         kAsRead | kAsWrite, "scratchData"));
        if (!b.dst_implicit.empty())
            model.record_access(c, write(b.dst_implicit.begin, b.dst_implicit.end, kAsBuild,
                                         kAsWrite, "dstImplicitData"));
        if (!b.dst_addresses.empty())
            model.record_access(c, write(b.dst_addresses.begin, b.dst_addresses.end, kAsBuild,
                                         kAsWrite, "dstAddressesArray"));
        if (!b.dst_sizes.empty())
            model.record_access(c, write(b.dst_sizes.begin, b.dst_sizes.end, kAsBuild, kAsWrite,
                                         "dstSizesArray"));
        return c;
    }
    CommandRef copy_buffer(AddressRange src, AddressRange dst) {
        const CommandRef c = next("vkCmdCopyBuffer");
        model.record_copy(c, read(src.begin, src.end, kCopy, kTransferRead, "srcBuffer"),
                          write(dst.begin, dst.end, kCopy, kTransferWrite, "dstBuffer"));
        return c;
    }
    CommandRef fill(AddressRange dst, const char* name = "vkCmdFillBuffer") {
        const CommandRef c = next(name);
        model.record_access(c, write(dst.begin, dst.end, kClear, kTransferWrite, "dstBuffer"));
        return c;
    }
    void barrier(StageMask src, AccessMask src_access, StageMask dst, AccessMask dst_access) {
        const MemoryBarrier b{src, src_access, dst, dst_access};
        model.pipeline_barrier(next("vkCmdPipelineBarrier2"),
                               DependencyInfo{std::span(&b, 1), {}, 0});
    }
    void buffer_barrier(AddressRange range, StageMask src, AccessMask src_access, StageMask dst,
                        AccessMask dst_access) {
        const BufferBarrier b{{src, src_access, dst, dst_access}, range};
        model.pipeline_barrier(next("vkCmdPipelineBarrier2"),
                               DependencyInfo{{}, std::span(&b, 1), 0});
    }
    void full_barrier() {
        barrier(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_WRITE_BIT,
                VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
                VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT);
    }

    const std::vector<HazardReport>& hazards() const { return model.hazards(); }
};

}  // namespace clastrace::replay::test
