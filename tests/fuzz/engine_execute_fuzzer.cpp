// SPDX-License-Identifier: Apache-2.0
// Fuzz target (docs/fuzzing.md): arbitrary bytes become a whole command and the memory
// it reads. The first bytes pick the op type, mode, flags, counts, strides and limits;
// every address field points into the fuzzed memory (or at 0 / past it). execute() must
// never crash, hang or allocate in proportion to a count rather than to memory.
#include "clastrace/engine/blas.h"
#include "clastrace/engine/execute.h"

#include <cstddef>
#include <cstdint>
#include <cstring>

using namespace clastrace::engine;

namespace {

struct Reader {
    const uint8_t* p;
    size_t n;
    template <class T>
    T take() {
        T v{};
        size_t k = sizeof(T) < n ? sizeof(T) : n;
        std::memcpy(&v, p, k);
        p += k;
        n -= k;
        return v;
    }
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size < 96) return 0;
    Reader r{data, 96};
    const uint64_t base = 0x100000000ull;
    const uint64_t mem_size = size - 96;
    MemoryImage memory;
    if (mem_size > 0) {
        memory.add_region(base, mem_size, 0, "fuzz");
        std::memcpy(memory.write_bytes(base, mem_size, {"fuzz", 0}).data(), data + 96, mem_size);
    }
    auto address = [&](uint16_t v) -> uint64_t {
        if (v == 0) return 0;
        return base + (mem_size ? v % (mem_size + 64) : 0);  // sometimes just past the end
    };
    VkClusterAccelerationStructureTriangleClusterInputNV tri{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottom{};
    VkClusterAccelerationStructureMoveObjectsInputNV move{};
    VkClusterAccelerationStructureCommandsInfoNV c{};
    c.input.opType = VkClusterAccelerationStructureOpTypeNV(r.take<uint8_t>() % 7);
    c.input.opMode = VkClusterAccelerationStructureOpModeNV(r.take<uint8_t>() % 4);
    c.addressResolutionFlags = r.take<uint8_t>() % 64;
    c.input.maxAccelerationStructureCount = r.take<uint32_t>();
    tri.vertexFormat =
        r.take<uint8_t>() % 2 ? VK_FORMAT_R32G32B32_SFLOAT : VK_FORMAT_R16G16B16A16_SFLOAT;
    tri.maxClusterTriangleCount = r.take<uint16_t>();
    tri.maxClusterVertexCount = r.take<uint16_t>();
    tri.maxTotalTriangleCount = r.take<uint32_t>();
    tri.maxTotalVertexCount = r.take<uint32_t>();
    tri.maxGeometryIndexValue = r.take<uint32_t>();
    tri.maxClusterUniqueGeometryCount = r.take<uint8_t>();
    bottom.maxTotalClusterCount = r.take<uint32_t>();
    bottom.maxClusterCountPerAccelerationStructure = r.take<uint32_t>();
    move.type = VkClusterAccelerationStructureTypeNV(r.take<uint8_t>() % 4);
    move.noMoveOverlap = r.take<uint8_t>() & 1;
    move.maxMovedBytes = r.take<uint32_t>();
    if (c.input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV)
        c.input.opInput.pMoveObjects = &move;
    else if (c.input.opType ==
             VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV)
        c.input.opInput.pClustersBottomLevel = &bottom;
    else
        c.input.opInput.pTriangleClusters = &tri;
    c.dstImplicitData = address(r.take<uint16_t>());
    c.scratchData = address(r.take<uint16_t>());
    c.dstAddressesArray = {address(r.take<uint16_t>()), r.take<uint16_t>(), r.take<uint16_t>()};
    c.dstSizesArray = {address(r.take<uint16_t>()), r.take<uint16_t>(), r.take<uint16_t>()};
    c.srcInfosArray = {address(r.take<uint16_t>()), r.take<uint8_t>(), r.take<uint16_t>()};
    c.srcInfosCount = address(r.take<uint16_t>());
    ObjectDirectory directory;
    ExecuteOptions options;
    options.directory = &directory;
    ExecutionRecord record = execute(c, memory, options);
    // Whatever got built must trace without trouble.
    for (const OpResult& op : record.ops) {
        if (!op.executed ||
            op.dst_type != VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV)
            continue;
        Ray ray{{0, 0, 10}, 0, {0.01f, 0.02f, -1}, 1e30f};
        (void)trace_bottom_level_closest(memory, op.dst_address, ray, 0, &directory);
    }
    return 0;
}
