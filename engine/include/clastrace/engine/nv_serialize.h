// SPDX-License-Identifier: Apache-2.0
// The engine's serialized form of its NV objects and vkCmdCopyMemoryToAccelerationStructureKHR
// (mode DESERIALIZE) into a VkAccelerationStructureNV.
//
// Layout (the header is the one the KHR extension defines for serialized data):
//   driverUUID[16] | compatibilityUUID[16] | serializedSize u64 | deserializedSize u64 |
//   handleCount u64 | handleCount x u64 handles | object bytes (deserializedSize)
// The engine writes one handle per instance record of a top-level object, in record order
// (0 for an inactive instance), and none for a bottom-level object. The object bytes are
// the NvObjectHeader format with every instance's engine address cleared. Deserializing
// takes each instance's reference from the handle list as it is in memory then (the
// application replaced them with the handles of the BLAS it created before
// deserializing), so relocation is exactly the spec's patching.
#pragma once

#include "clastrace/engine/execution_record.h"
#include "clastrace/engine/memory_image.h"
#include "clastrace/engine/nv_build.h"

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace clastrace::engine {

using Uuid = std::array<uint8_t, 16>;
inline constexpr Uuid kEngineDriverUuid = {'c', 'l', 'a', 's', 't', 'r', 'a', 'c',
                                           'e', '-', 'e', 'n', 'g', 'i', 'n', 'e'};
inline constexpr Uuid kEngineNvCompatibilityUuid = {'c', 'l', 'a', 's', 't', 'r', 'a', 'c',
                                                    'e', '-', 'n', 'v', 'a', 's', '-', '1'};

struct SerializedHeader {
    uint8_t driver_uuid[16];
    uint8_t compatibility_uuid[16];
    uint64_t serialized_size;
    uint64_t deserialized_size;
    uint64_t handle_count;
};
static_assert(sizeof(SerializedHeader) == 56);

// The engine's vkCmdCopyAccelerationStructureToMemoryKHR of the object at `address`;
// empty with `error` when no checked NV object is there.
std::vector<std::byte> serialize_nv_object(const MemoryImage& memory, uint64_t address,
                                           std::string* error);

struct NvDeserializeCommand {
    uint64_t src_address = 0;  // pInfo->src.deviceAddress
    NvObjectBinding dst;
    uint32_t mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR;
};

struct NvDeserializeOptions {
    // Handle -> engine address of a created bottom-level object (nullopt: no such object).
    // Default: the handle is the address.
    std::function<std::optional<uint64_t>(uint64_t handle)> resolve_handle;
    // The capturing device's compatibility UUID when known: a blob with it is the driver's
    // own (opaque but compatible); any other foreign UUID breaks pInfo-03414.
    std::optional<Uuid> device_compatibility_uuid;
};

struct NvDeserializeResult {
    ExecutionRecord record;  // ops[0]: the object written (executed, dst_address, dst_size)
    bool header_read = false;
    bool opaque = false;  // another driver's blob: checked, not decoded
    SerializedHeader header{};
    std::vector<uint64_t> handles;  // as in memory (opaque blobs too)
    bool top_level = false;
};

NvDeserializeResult execute_nv_deserialize(const NvDeserializeCommand& command, MemoryImage& memory,
                                           const NvDeserializeOptions& options = {});

inline constexpr uint64_t kSerializedAlignment = 256;
inline constexpr const char* kVuidDeserializeFeature =
    "VUID-vkCmdCopyMemoryToAccelerationStructureKHR-accelerationStructure-08927";
inline constexpr const char* kVuidDeserializeSrcAddress =
    "VUID-vkCmdCopyMemoryToAccelerationStructureKHR-pInfo-03742";
inline constexpr const char* kVuidDeserializeSrcAlign =
    "VUID-vkCmdCopyMemoryToAccelerationStructureKHR-pInfo-03743";
// No VUID says the source buffer must hold serializedSize bytes (03744 is about binding):
// the tool's own rule (docs/spec-readings.md).
inline constexpr const char* kRuleDeserializeSrcPastBuffer =
    "CLASTRACE-deserialize-source-past-buffer";
inline constexpr const char* kVuidDeserializeDstBound =
    "VUID-vkCmdCopyMemoryToAccelerationStructureKHR-buffer-03745";
inline constexpr const char* kVuidDeserializeContents =
    "VUID-VkCopyMemoryToAccelerationStructureInfoKHR-src-04960";
inline constexpr const char* kVuidDeserializeMode =
    "VUID-VkCopyMemoryToAccelerationStructureInfoKHR-mode-03413";
inline constexpr const char* kVuidDeserializeCompatible =
    "VUID-VkCopyMemoryToAccelerationStructureInfoKHR-pInfo-03414";
inline constexpr const char* kVuidDeserializeDstSize =
    "VUID-VkCopyMemoryToAccelerationStructureInfoKHR-dst-03746";
inline constexpr const char* kRuleSerializedOpaque =
    "CLASTRACE-serialized-blob-from-another-driver";
inline constexpr const char* kRuleDeserializeHandleUnknown =
    "CLASTRACE-deserialize-handle-names-no-created-object";
inline constexpr const char* kRuleDeserializeTypeDiffers =
    "CLASTRACE-deserialize-type-differs-from-dst";
inline constexpr const char* kRuleDeserializeOverlap = "CLASTRACE-deserialize-source-overlaps-dst";

}  // namespace clastrace::engine
