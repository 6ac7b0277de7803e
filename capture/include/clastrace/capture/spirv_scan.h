// SPDX-License-Identifier: Apache-2.0
// A bounds-checked reader of a SPIR-V module's word stream that answers three questions: may the
// module's shaders reach memory through buffer device addresses (physical storage buffer
// pointers)? The capture marks a dispatch whose pipeline has such a shader as a possible writer
// of all device-address memory (docs/replay.md, "Possible hazards"). Do they trace rays with ray
// queries? The capture then records the dispatch or draw with the acceleration structures it
// can reach (capture/README.md, "Consumers of acceleration structures"). Do they turn a value
// read from memory into an acceleration structure? The capture then looks for structure
// addresses in the buffers bound to them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

namespace clastrace::capture {

// SPIR-V numbers the scan looks for (the SPIR-V specification, sections 3.31 and 3.7).
inline constexpr uint32_t kSpirvMagic = 0x07230203u;
inline constexpr uint32_t kSpirvCapabilityPhysicalStorageBufferAddresses = 5347u;
inline constexpr uint32_t kSpirvStorageClassPhysicalStorageBuffer = 5349u;
inline constexpr uint32_t kSpirvCapabilityRayQueryProvisionalKHR = 4471u;
inline constexpr uint32_t kSpirvCapabilityRayQueryKHR = 4472u;
inline constexpr uint32_t kSpirvOpTypeRayQueryKHR = 4472u;  // same number, an opcode
inline constexpr uint32_t kSpirvOpConvertUToAccelerationStructureKHR = 4447u;

struct SpirvScan {
    bool valid = false;
    // The module declares OpCapability PhysicalStorageBufferAddresses.
    bool declares_address_capability = false;
    // An OpTypePointer, OpTypeForwardPointer or OpVariable names the PhysicalStorageBuffer
    // storage class: some instruction can load or store through a device address.
    bool uses_address_pointers = false;
    // OpCapability RayQueryKHR (or the provisional one) or an OpTypeRayQueryKHR: the shader
    // may trace rays through ray queries, reading acceleration structures.
    bool uses_ray_queries = false;
    // OpConvertUToAccelerationStructureKHR turns a 64-bit value into an acceleration structure:
    // a value loaded from push constants, or one from anywhere else (a storage or uniform
    // buffer, a pointer, or an origin the scan does not follow). The capture then compares the
    // bytes of the buffers bound to the consumer with the known structure addresses
    // (capture/README.md, "Consumers of acceleration structures", source 4).
    bool converts_push_constant_addresses = false;
    bool converts_addresses_from_memory = false;
    // Where the scan stopped on a malformed module: the word index and the rule broken.
    std::size_t error_word = 0;
    std::string error;
    // What the capture records: the shader may write through a device address. The scan does
    // not follow which pointers are stored to, so a shader that only reads through addresses
    // counts too (a possible writer, never a missed one).
    bool may_write_through_addresses() const {
        return valid && declares_address_capability && uses_address_pointers;
    }
};

// Scans `words` (a whole module, header first, either byte order). Never reads past the span.
SpirvScan scan_spirv(std::span<const uint32_t> words);
// The same over raw bytes as vkCreateShaderModule receives them (codeSize bytes); a size that
// is not a multiple of 4 is malformed.
SpirvScan scan_spirv_bytes(const void* code, std::size_t code_size);

}  // namespace clastrace::capture
