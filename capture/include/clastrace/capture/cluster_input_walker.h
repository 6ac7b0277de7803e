// SPDX-License-Identifier: Apache-2.0
// Follows the pointers of one vkCmdBuildClusterAccelerationStructureIndirectNV through device
// memory: the count, the srcInfosArray entries, and from each entry exactly the index, vertex,
// geometry-index, opacity-micromap-index, bounds and cluster-reference bytes it references.
// Pure logic over a memory reader, so it is tested without a GPU.
#pragma once

#include "clastrace/capture/capture_records.h"

#include <functional>

namespace clastrace::capture {

// Reads [address, address + size) into `out` (a copy, or a view where the reader's memory
// stays unchanged); with `out` null only checks that it could. False + `why` when the range is
// not readable.
using DeviceMemoryReader = std::function<bool(VkDeviceAddress address, uint64_t size,
                                              CapturedBytes* out, std::string& why)>;

struct ClusterMemoryWalk {
    uint32_t executed_count = 0;
    std::vector<CapturedRange> ranges;
    std::vector<CaptureIssue> issues;
    std::vector<uint32_t>
        template_vertex_counts;  // template builds: vertexCount of each executed entry
};

// The vertex count of the template at `templateAddress`, as its build's src info gave it;
// false when the layer did not see that template built. An instantiation reads that many
// vertices from its vertexBuffer.
using TemplateVertexCountLookup =
    std::function<bool(VkDeviceAddress template_address, uint32_t* vertex_count)>;

// What the command reads, to be called while the queue is stopped just before it.
ClusterMemoryWalk walk_cluster_inputs(const ClusterCommandParameters& parameters,
                                      const DeviceMemoryReader& read,
                                      const TemplateVertexCountLookup& template_vertex_count = {});

// What the command wrote, to be called while the queue is stopped just after it.
ClusterMemoryWalk walk_cluster_outputs(const ClusterCommandParameters& parameters,
                                       uint32_t executed_count, const DeviceMemoryReader& read);

// A guard against hostile counts: a command whose followed ranges exceed this is cut short
// with an issue instead of exhausting the captured process's memory.
inline constexpr uint64_t kMaxCapturedBytesPerCommand = uint64_t(1) << 30;

}  // namespace clastrace::capture
