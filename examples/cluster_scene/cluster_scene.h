// SPDX-License-Identifier: Apache-2.0
// The sample's scene: every op of VK_NV_cluster_acceleration_structure over one clustered
// mesh, recorded in one command buffer whose src infos are written by GPU copies from a
// staging buffer, with the barriers the spec requires (each can be left out by name).
#pragma once

#include "mesh_clusters.h"
#include "vulkan_context.h"

#include <functional>
#include <set>
#include <string>
#include <vector>

namespace cluster_scene {

// A barrier the scene records, and what leaving it out breaks.
struct BarrierInfo {
    const char* name;
    const char* orders;  // "<earlier command> -> <later command>: <what>"
};
// The barriers of the copy variant, or of --compute-infos (dispatch-to-sizes for copy-to-sizes).
const std::vector<BarrierInfo>& barrierCatalogue(bool computeInfos = false);

struct SceneOptions {
    std::set<std::string> skipBarriers;  // names from barrierCatalogue()
    // The cluster infos and their count are written by a compute dispatch through buffer device
    // addresses (shaders/copy_words.comp) instead of vkCmdCopyBuffer; barrier dispatch-to-sizes.
    bool computeInfos = false;
    // With computeInfos: one more dispatch of the same shader copies the cluster infos into a
    // buffer no command reads, with no barrier after it (a writer whose bytes no build sees).
    bool computeElsewhere = false;
    uint32_t queueIndex = 0;                // which of the context's queues to submit to
    std::function<void()> beforeRecording;  // called once resources exist (threads line up here)
};

// What one vkCmdBuildClusterAccelerationStructureIndirectNV wrote, read back after the fence.
struct BuildOutputs {
    std::string label;
    uint32_t opType = 0, opMode = 0, ops = 0;
    uint64_t dstAddressesArray = 0, dstSizesArray = 0, dstImplicitData = 0;
    std::vector<uint64_t> addresses;      // implicit mode: where each object went
    std::vector<uint32_t> sizes;          // bytes of each object
    std::vector<uint64_t> objectDigests;  // FNV-1a 64 of each object's bytes (implicit mode)
    std::string addressesHex, sizesHex;   // the two arrays' bytes as read back
};

struct SceneResult {
    uint64_t commandBuffer = 0;         // the handle, as the trace names it
    std::vector<std::string> commands;  // "copy:...", "dispatch:...", "barrier:NAME", "build:..."
    uint32_t copies = 0, dispatches = 0, barriers = 0, builds = 0;
    std::vector<BuildOutputs> outputs;  // one per build, in record order
    // --compute-infos: the device-address ranges (address, bytes) the dispatch writes, so a
    // replay's hazards can be judged true or false (bench/capture/address_writes_bench.cpp).
    std::vector<std::pair<uint64_t, uint64_t>> computeWrites;
};

// Creates the scene's buffers, records and submits its command buffer, waits, reads back
// and frees everything. Throws VulkanError / std::runtime_error with the reason.
SceneResult runScene(VulkanContext& context, const ClusteredMesh& mesh,
                     const SceneOptions& options);

uint64_t fnv1a64(const uint8_t* data, size_t size);

}  // namespace cluster_scene
