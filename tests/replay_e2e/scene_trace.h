// SPDX-License-Identifier: Apache-2.0
// Small traces for replay tests, written with the TraceWriter: one command buffer of
// cluster builds, copies and barriers, one submission, like a capture would record them.
#pragma once

#include <clastrace/trace_building/engine_mirror.h>
#include <clastrace/trace_building/record_writer.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace clastrace::test {

// Buffers every scene has (device addresses fixed so tests can name bytes).
struct SceneBuffers {
    static constexpr uint64_t kVertices = 0x10000000, kIndices = 0x10010000, kInfos = 0x10020000,
                              kDst = 0x10100000, kDst2 = 0x10200000, kAddresses = 0x10030000,
                              kAddresses2 = 0x10031000, kSizes = 0x10032000, kSizes2 = 0x10033000,
                              kScratch = 0x10040000, kBlasInfos = 0x10050000, kBlasDst = 0x10300000;
};

struct BuildCall {
    uint64_t dst = SceneBuffers::kDst;
    uint64_t addresses = SceneBuffers::kAddresses;
    uint64_t sizes = SceneBuffers::kSizes;
    uint64_t scratch = SceneBuffers::kScratch;
    uint32_t first_cluster_id = 100;
    bool capture_outputs = true;  // write the engine's outputs into the trace as captured outputs
    uint64_t corrupt_output_byte = 0;  // != 0: flip this byte of the captured dst bytes
    // The input's vertexFormat and opType by their bits: a hostile trace's may be past the
    // enums' range (common/enum_bits.h).
    uint32_t vertex_format = VK_FORMAT_R32G32B32_SFLOAT;
    uint32_t op_type = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
};

class SceneTrace {
public:
    // engine_device: the header says the trace was made by clastrace's engine.
    SceneTrace(const std::string& path, bool engine_device, uint64_t scratch_size = 4096);
    ~SceneTrace();
    // vkCmdBuildClusterAccelerationStructureIndirectNV of two triangle clusters.
    void build(const BuildCall& call);
    // srcInfosArray contents written by vkCmdCopyBuffer from a staging buffer.
    void copy_infos();
    void barrier(uint64_t src_stage, uint64_t src_access, uint64_t dst_stage, uint64_t dst_access);
    // vkCmdPipelineBarrier (v1): one VkMemoryBarrier with the call's stage masks.
    void barrier_v1(uint32_t src_stage, uint32_t src_access, uint32_t dst_stage,
                    uint32_t dst_access);
    // vkCmdSetEvent2 / vkCmdWaitEvents2 with one VkMemoryBarrier2.
    void set_event(uint64_t event, uint64_t src_stage, uint64_t src_access, uint64_t dst_stage,
                   uint64_t dst_access);
    void wait_event(uint64_t event, uint64_t src_stage, uint64_t src_access, uint64_t dst_stage,
                    uint64_t dst_access);
    // Moves the clusters at these (captured) addresses into implicit destinations at kBlasDst.
    void move_clusters(const std::vector<uint64_t>& cluster_addresses);
    // A BLAS over the clusters at these (captured) addresses.
    void build_blas(const std::vector<uint64_t>& cluster_addresses);
    // Ends the command buffer and submits it to `queue` (binary semaphores, 0 = none);
    // later commands go into a fresh command buffer.
    void submit(uint64_t queue, uint64_t wait_semaphore = 0, uint64_t signal_semaphore = 0,
                uint64_t fence = 0);
    void wait_fence(uint64_t fence);
    // The capture saw mapped memory at `address` hold `bytes` (a host write, between submissions).
    // `reason` as MemoryObservation.reason (4: the command read these bytes, changed after submit).
    void observe(uint64_t address, const std::vector<uint8_t>& bytes, uint32_t reason = 0);
    // Ends the command buffer, submits, waits on the fence, finishes the file.
    void finish();

    std::vector<VkClusterAccelerationStructureBuildTriangleClusterInfoNV> infos;
    // Driver-style traces: captured dstAddressesArray values differ from the engine's by this.
    uint64_t driver_address_shift = 0;

private:
    void add_buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage,
                    uint64_t memory, uint64_t offset);
    void emit_build(
        const VkClusterAccelerationStructureCommandsInfoNV& info, const BuildCall& call,
        std::vector<std::pair<uint64_t, std::vector<uint8_t>>> inputs,
        uint64_t translated_base_shift,
        const std::vector<std::pair<uint64_t, std::vector<uint8_t>>>& mirror_patch = {});
    trace_building::EngineMirror mirror_;
    trace_building::RecordWriter writer_;
    std::vector<float> vertices_;
    std::vector<uint8_t> indices_;
    uint64_t scratch_size_;
    bool engine_device_;
    uint64_t command_buffer_;
};

}  // namespace clastrace::test
