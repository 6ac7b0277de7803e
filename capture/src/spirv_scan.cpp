// SPDX-License-Identifier: Apache-2.0
// The SPIR-V word-stream scan (spirv_scan.h). Every instruction is read through its own word
// count, checked against the words left, so a truncated or hostile module ends the scan with an
// error instead of a read past the buffer.
#include "clastrace/capture/spirv_scan.h"

#include <cstring>
#include <unordered_map>
#include <vector>

namespace clastrace::capture {
namespace {

constexpr std::size_t kHeaderWords = 5;
constexpr uint32_t kOpCapability = 17;
constexpr uint32_t kOpTypePointer = 32;         // result id, storage class, type
constexpr uint32_t kOpTypeForwardPointer = 39;  // pointer type, storage class
constexpr uint32_t kOpVariable = 59;            // result type, result id, storage class
constexpr uint32_t kOpLoad = 61;                // result type, result id, pointer
constexpr uint32_t kOpAccessChain = 65;         // result type, result id, base, indexes
constexpr uint32_t kOpInBoundsAccessChain = 66;
constexpr uint32_t kOpPtrAccessChain = 67;
constexpr uint32_t kOpInBoundsPtrAccessChain = 70;
constexpr uint32_t kOpCompositeExtract = 81;  // result type, result id, composite, indexes
constexpr uint32_t kOpCopyObject = 83;        // result type, result id, operand
constexpr uint32_t kOpUConvert = 113;
constexpr uint32_t kOpBitcast = 124;
constexpr uint32_t kStorageClassPushConstant = 9;

// Where the values an OpConvertUToAccelerationStructureKHR may convert come from: the storage
// class of each pointer (variables and the access chains into them) and of the memory each
// loaded value was read from, carried through extracts, copies and bitcasts. Definitions come
// before uses in SPIR-V (OpPhi aside), so one pass in module order sees every one it needs.
struct AddressOrigins {
    std::unordered_map<uint32_t, uint32_t> pointer_class;  // pointer id -> storage class
    std::unordered_map<uint32_t, uint32_t> loaded_from;    // value id -> storage class

    void note(std::span<const uint32_t> instruction, uint32_t opcode, SpirvScan* scan);
    void converted(uint32_t value, SpirvScan* scan) const;
};

uint32_t byte_swapped(uint32_t w) { return __builtin_bswap32(w); }

// The operand of an instruction at `operand` (0 = the word after the opcode word), or none.
bool operand(std::span<const uint32_t> instruction, std::size_t index, uint32_t* out) {
    if (index + 1 >= instruction.size()) return false;
    *out = instruction[index + 1];
    return true;
}

// The class `map` holds for `id`, or none.
bool class_of(const std::unordered_map<uint32_t, uint32_t>& map, uint32_t id, uint32_t* out) {
    auto it = map.find(id);
    if (it == map.end()) return false;
    *out = it->second;
    return true;
}

void AddressOrigins::note(std::span<const uint32_t> instruction, uint32_t opcode, SpirvScan* scan) {
    uint32_t result = 0, source = 0, storage_class = 0;
    if (!operand(instruction, 1, &result) || !operand(instruction, 2, &source)) return;
    switch (opcode) {
    case kOpVariable: pointer_class[result] = source; break;
    case kOpAccessChain:
    case kOpInBoundsAccessChain:
    case kOpPtrAccessChain:
    case kOpInBoundsPtrAccessChain:
        if (class_of(pointer_class, source, &storage_class)) pointer_class[result] = storage_class;
        break;
    case kOpLoad:
        if (class_of(pointer_class, source, &storage_class)) loaded_from[result] = storage_class;
        break;
    case kOpCompositeExtract:
    case kOpCopyObject:
    case kOpUConvert:
    case kOpBitcast:
        if (class_of(loaded_from, source, &storage_class)) loaded_from[result] = storage_class;
        break;
    case kSpirvOpConvertUToAccelerationStructureKHR: converted(source, scan); break;
    default: break;
    }
}

// A value read from push constants is followed already (every push-constant value is compared
// with the known addresses); any other one, loaded from a buffer or of an origin this pass does
// not follow (arithmetic, a function parameter, a phi), may come from memory.
void AddressOrigins::converted(uint32_t value, SpirvScan* scan) const {
    uint32_t storage_class = 0;
    if (class_of(loaded_from, value, &storage_class) && storage_class == kStorageClassPushConstant)
        scan->converts_push_constant_addresses = true;
    else
        scan->converts_addresses_from_memory = true;
}

void note_instruction(std::span<const uint32_t> instruction, uint32_t opcode, SpirvScan* scan) {
    uint32_t value = 0;
    switch (opcode) {
    case kOpCapability:
        if (!operand(instruction, 0, &value)) break;
        if (value == kSpirvCapabilityPhysicalStorageBufferAddresses)
            scan->declares_address_capability = true;
        if (value == kSpirvCapabilityRayQueryKHR || value == kSpirvCapabilityRayQueryProvisionalKHR)
            scan->uses_ray_queries = true;
        break;
    case kSpirvOpTypeRayQueryKHR: scan->uses_ray_queries = true; break;
    case kOpTypePointer:
    case kOpTypeForwardPointer:
        if (operand(instruction, 1, &value) && value == kSpirvStorageClassPhysicalStorageBuffer)
            scan->uses_address_pointers = true;
        break;
    case kOpVariable:
        if (operand(instruction, 2, &value) && value == kSpirvStorageClassPhysicalStorageBuffer)
            scan->uses_address_pointers = true;
        break;
    default: break;
    }
}

SpirvScan fail(SpirvScan scan, std::size_t word, std::string rule) {
    scan.valid = false;
    scan.error_word = word;
    scan.error = std::move(rule);
    return scan;
}

}  // namespace

SpirvScan scan_spirv(std::span<const uint32_t> words) {
    SpirvScan scan;
    if (words.size() < kHeaderWords)
        return fail(scan, words.size(), "module shorter than the 5-word SPIR-V header");
    bool swapped = false;
    if (words[0] != kSpirvMagic) {
        if (byte_swapped(words[0]) != kSpirvMagic)
            return fail(scan, 0, "first word is not the SPIR-V magic number 0x07230203");
        swapped = true;
    }
    std::vector<uint32_t> native;
    if (swapped) {  // rare: a module written on a machine of the other byte order
        native.reserve(words.size());
        for (uint32_t w : words) native.push_back(byte_swapped(w));
        words = native;
    }
    AddressOrigins origins;
    for (std::size_t at = kHeaderWords; at < words.size();) {
        const uint32_t count = words[at] >> 16;
        const uint32_t opcode = words[at] & 0xFFFFu;
        if (count == 0) return fail(scan, at, "instruction with a word count of 0");
        if (count > words.size() - at)
            return fail(scan, at,
                        "instruction's word count " + std::to_string(count) + " runs past the " +
                            std::to_string(words.size()) + "-word module");
        note_instruction(words.subspan(at, count), opcode, &scan);
        origins.note(words.subspan(at, count), opcode, &scan);
        at += count;
    }
    scan.valid = true;
    return scan;
}

SpirvScan scan_spirv_bytes(const void* code, std::size_t code_size) {
    if (code_size % 4 != 0) {
        SpirvScan scan;
        return fail(scan, code_size / 4,
                    "codeSize " + std::to_string(code_size) + " is not a multiple of 4");
    }
    if (!code) return fail(SpirvScan{}, 0, "no code");
    // pCode is uint32_t-aligned by the spec, but a copy costs little and keeps the scan safe on
    // any pointer a fuzzer hands in.
    std::vector<uint32_t> words(code_size / 4);
    if (code_size) std::memcpy(words.data(), code, code_size);
    return scan_spirv(words);
}

}  // namespace clastrace::capture
