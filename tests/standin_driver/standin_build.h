// SPDX-License-Identifier: MIT
// One cluster build as the stand-in driver executes it, on the host, against memory the host
// maps (README.md: the engine builds, the stand-in places the objects per its own layout).
#pragma once

#include <clastrace/engine/object_directory.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <vector>

namespace clastrace::standin {

// A buffer with a device address whose bytes the host reaches at `host`.
struct HostBuffer {
    uint64_t address = 0;
    uint64_t size = 0;
    uint8_t* host = nullptr;
    VkBufferUsageFlags usage = 0;
};

// A recorded vkCmdBuildClusterAccelerationStructureIndirectNV with the op input it points to.
struct RecordedBuild {
    VkClusterAccelerationStructureCommandsInfoNV info{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottom_level{};
    VkClusterAccelerationStructureTriangleClusterInputNV triangle_clusters{};
    VkClusterAccelerationStructureMoveObjectsInputNV move_objects{};

    explicit RecordedBuild(const VkClusterAccelerationStructureCommandsInfoNV& recorded);
    RecordedBuild(const RecordedBuild&) = delete;
    RecordedBuild& operator=(const RecordedBuild&) = delete;
};

// Executes `build` on the bytes of `buffers` and writes its outputs back through their host
// pointers. `directory` keeps the objects built so far (bottom levels look their clusters up).
// Returns the number of findings the engine reported (0 for a correct command).
size_t execute_on_host(const RecordedBuild& build, const std::vector<HostBuffer>& buffers,
                       engine::ObjectDirectory& directory);

}  // namespace clastrace::standin
