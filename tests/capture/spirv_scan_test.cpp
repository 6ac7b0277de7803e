// SPDX-License-Identifier: Apache-2.0
// The SPIR-V scan on hand-written word streams: a module that stores through a physical storage
// buffer pointer is marked, one without the capability or the storage class is not, malformed
// modules are rejected with the word and rule, and no truncation or corruption reads out of
// bounds (run under the sanitizer builds).
#include "clastrace/capture/spirv_scan.h"

#include <gtest/gtest.h>

#include <random>
#include <vector>

namespace clastrace::capture {
namespace {

constexpr uint32_t op(uint32_t count, uint32_t opcode) { return count << 16 | opcode; }

constexpr uint32_t kCapabilityShader = 1;
constexpr uint32_t kStorageClassStorageBuffer = 12;

// A compute-shader-like skeleton: header, capabilities, then the type declarations given.
std::vector<uint32_t> module(std::vector<uint32_t> capabilities, std::vector<uint32_t> body) {
    std::vector<uint32_t> words = {kSpirvMagic, 0x00010500, 0, 20, 0};
    for (uint32_t c : capabilities) words.insert(words.end(), {op(2, 17), c});
    words.insert(words.end(),
                 {op(3, 14), 5348u, 1});  // OpMemoryModel PhysicalStorageBuffer64 GLSL450
    words.insert(words.end(), body.begin(), body.end());
    return words;
}

// %uint = OpTypeInt 32 0; %ptr = OpTypePointer <class> %uint; OpStore %p %v (ids only).
std::vector<uint32_t> pointer_and_store(uint32_t storage_class) {
    return {op(4, 21), 2, 32, 0, op(4, 32), 3, storage_class, 2, op(3, 62), 4, 5};
}

TEST(SpirvScan, AddressCapabilityAndPointerMarkAWriter) {
    const auto words = module({kCapabilityShader, kSpirvCapabilityPhysicalStorageBufferAddresses},
                              pointer_and_store(kSpirvStorageClassPhysicalStorageBuffer));
    const SpirvScan scan = scan_spirv(words);
    ASSERT_TRUE(scan.valid) << scan.error;
    EXPECT_TRUE(scan.declares_address_capability);
    EXPECT_TRUE(scan.uses_address_pointers);
    EXPECT_TRUE(scan.may_write_through_addresses());
}

TEST(SpirvScan, ForwardPointerAndVariableCountToo) {
    const auto forward = module({kSpirvCapabilityPhysicalStorageBufferAddresses},
                                {op(3, 39), 7, kSpirvStorageClassPhysicalStorageBuffer});
    EXPECT_TRUE(scan_spirv(forward).may_write_through_addresses());
    const auto variable = module({kSpirvCapabilityPhysicalStorageBufferAddresses},
                                 {op(4, 59), 3, 8, kSpirvStorageClassPhysicalStorageBuffer});
    EXPECT_TRUE(scan_spirv(variable).may_write_through_addresses());
}

TEST(SpirvScan, StorageBuffersAloneAreNotAddressWriters) {
    const auto words = module({kCapabilityShader}, pointer_and_store(kStorageClassStorageBuffer));
    const SpirvScan scan = scan_spirv(words);
    ASSERT_TRUE(scan.valid) << scan.error;
    EXPECT_FALSE(scan.declares_address_capability);
    EXPECT_FALSE(scan.uses_address_pointers);
    EXPECT_FALSE(scan.may_write_through_addresses());
}

TEST(SpirvScan, CapabilityWithoutAddressPointersIsNotAWriter) {
    const auto words = module({kSpirvCapabilityPhysicalStorageBufferAddresses},
                              pointer_and_store(kStorageClassStorageBuffer));
    const SpirvScan scan = scan_spirv(words);
    EXPECT_TRUE(scan.declares_address_capability);
    EXPECT_FALSE(scan.may_write_through_addresses());
}

TEST(SpirvScan, ByteSwappedModuleIsRead) {
    auto words = module({kSpirvCapabilityPhysicalStorageBufferAddresses},
                        pointer_and_store(kSpirvStorageClassPhysicalStorageBuffer));
    for (uint32_t& w : words) w = __builtin_bswap32(w);
    EXPECT_TRUE(scan_spirv(words).may_write_through_addresses());
}

TEST(SpirvScan, MalformedModulesNameTheWordAndRule) {
    EXPECT_EQ(scan_spirv(std::vector<uint32_t>{kSpirvMagic, 0}).error,
              "module shorter than the 5-word SPIR-V header");
    const SpirvScan magic = scan_spirv(std::vector<uint32_t>{1, 2, 3, 4, 5});
    EXPECT_FALSE(magic.valid);
    EXPECT_EQ(magic.error_word, 0u);

    auto zero = module({}, {0u});
    const SpirvScan zero_count = scan_spirv(zero);
    EXPECT_FALSE(zero_count.valid);
    EXPECT_EQ(zero_count.error_word, zero.size() - 1);
    EXPECT_EQ(zero_count.error, "instruction with a word count of 0");

    // The pointer declaration claims 9 words where 4 are left: the scan stops there, unmarked.
    auto past = module({kSpirvCapabilityPhysicalStorageBufferAddresses},
                       {op(9, 32), 3, kSpirvStorageClassPhysicalStorageBuffer, 2});
    const SpirvScan runs_past = scan_spirv(past);
    EXPECT_FALSE(runs_past.valid);
    EXPECT_EQ(runs_past.error_word, past.size() - 4);
    EXPECT_FALSE(runs_past.may_write_through_addresses());

    EXPECT_FALSE(scan_spirv_bytes(past.data(), 7).valid);
    EXPECT_EQ(scan_spirv_bytes(past.data(), 7).error, "codeSize 7 is not a multiple of 4");
}

// Ray queries: the capability alone (a module whose queries sit in functions the scan does not
// follow), the type alone (the provisional capability's modules), or both mark the module; a
// module that traces with neither is not marked.
TEST(SpirvScan, RayQueryCapabilityOrTypeMarksARayQueryUser) {
    constexpr uint32_t kCapabilityRayTracingKHR = 4479;
    const auto capability = module({kCapabilityShader, kSpirvCapabilityRayQueryKHR}, {});
    const SpirvScan by_capability = scan_spirv(capability);
    ASSERT_TRUE(by_capability.valid) << by_capability.error;
    EXPECT_TRUE(by_capability.uses_ray_queries);
    EXPECT_FALSE(by_capability.may_write_through_addresses());

    // %rq = OpTypeRayQueryKHR (one result id).
    const auto type = module({kCapabilityShader, kSpirvCapabilityRayQueryProvisionalKHR},
                             {op(2, kSpirvOpTypeRayQueryKHR), 9});
    EXPECT_TRUE(scan_spirv(type).uses_ray_queries);
    const auto type_only = module({kCapabilityShader}, {op(2, kSpirvOpTypeRayQueryKHR), 9});
    EXPECT_TRUE(scan_spirv(type_only).uses_ray_queries);

    const auto pipeline_rays = module({kCapabilityShader, kCapabilityRayTracingKHR},
                                      pointer_and_store(kStorageClassStorageBuffer));
    EXPECT_FALSE(scan_spirv(pipeline_rays).uses_ray_queries);
    EXPECT_FALSE(scan_spirv(module({kCapabilityShader}, {})).uses_ray_queries);
}

// %ptr = OpTypePointer <class> %ulong; %var = OpVariable %ptr <class>; %chain = OpAccessChain
// %ptr %var %zero; %value = OpLoad %ulong %chain; then `convert` turns `%value` (or its bitcast)
// into an acceleration structure with OpConvertUToAccelerationStructureKHR.
std::vector<uint32_t> load_and_convert(uint32_t storage_class, bool through_bitcast) {
    constexpr uint32_t kUlong = 2, kPtr = 3, kVar = 4, kChain = 5, kValue = 6, kCast = 7, kZero = 8,
                       kStructureType = 9, kStructure = 10;
    std::vector<uint32_t> words = {op(4, 21), kUlong,        64,
                                   0,  // OpTypeInt 64 0
                                   op(4, 32), kPtr,          storage_class,
                                   kUlong,    op(4, 59),     kPtr,
                                   kVar,      storage_class, op(5, 65),
                                   kPtr,      kChain,        kVar,
                                   kZero,     op(4, 61),     kUlong,
                                   kValue,    kChain};
    uint32_t converted = kValue;
    if (through_bitcast) {
        words.insert(words.end(), {op(4, 124), kUlong, kCast, kValue});
        converted = kCast;
    }
    words.insert(words.end(), {op(4, kSpirvOpConvertUToAccelerationStructureKHR), kStructureType,
                               kStructure, converted});
    return words;
}

// A 64-bit value loaded from a storage or uniform buffer and converted to an acceleration
// structure marks the module (the capture then reads its bound buffers); one loaded from push
// constants marks it as a push-constant converter only (those are followed already); a module
// that converts nothing is marked as neither.
TEST(SpirvScan, ConvertingALoadedValueToAStructureIsToldApartFromPushConstants) {
    constexpr uint32_t kStorageClassUniform = 2, kStorageClassPushConstant = 9;
    for (uint32_t storage_class : {kStorageClassStorageBuffer, kStorageClassUniform}) {
        for (bool bitcast : {false, true}) {
            SCOPED_TRACE(storage_class * 10 + bitcast);
            const SpirvScan scan = scan_spirv(
                module({kSpirvCapabilityRayQueryKHR}, load_and_convert(storage_class, bitcast)));
            ASSERT_TRUE(scan.valid) << scan.error;
            EXPECT_TRUE(scan.converts_addresses_from_memory);
            EXPECT_FALSE(scan.converts_push_constant_addresses);
        }
    }
    const SpirvScan pushed = scan_spirv(
        module({kSpirvCapabilityRayQueryKHR}, load_and_convert(kStorageClassPushConstant, true)));
    ASSERT_TRUE(pushed.valid) << pushed.error;
    EXPECT_FALSE(pushed.converts_addresses_from_memory);
    EXPECT_TRUE(pushed.converts_push_constant_addresses);

    const SpirvScan plain = scan_spirv(
        module({kSpirvCapabilityRayQueryKHR}, pointer_and_store(kStorageClassStorageBuffer)));
    EXPECT_FALSE(plain.converts_addresses_from_memory);
    EXPECT_FALSE(plain.converts_push_constant_addresses);
}

// A converted value of an origin the scan does not follow (here an id it never saw defined,
// as a function parameter or a phi would be) may come from memory: marked, never missed.
TEST(SpirvScan, ConvertedValueOfUnknownOriginCountsAsFromMemory) {
    const SpirvScan scan =
        scan_spirv(module({kSpirvCapabilityRayQueryKHR},
                          {op(4, kSpirvOpConvertUToAccelerationStructureKHR), 9, 10, 77}));
    ASSERT_TRUE(scan.valid) << scan.error;
    EXPECT_TRUE(scan.converts_addresses_from_memory);
}

// What a fuzzer would try, deterministically: every truncation and many random corruptions of a
// marked module scan without reading outside the span (ASan/UBSan builds check that).
TEST(SpirvScan, TruncatedAndCorruptedModulesStayInBounds) {
    const auto words = module({kSpirvCapabilityPhysicalStorageBufferAddresses},
                              pointer_and_store(kSpirvStorageClassPhysicalStorageBuffer));
    for (std::size_t n = 0; n <= words.size(); ++n) {
        std::vector<uint32_t> cut(words.begin(), words.begin() + n);  // own buffer: exact bounds
        const SpirvScan scan = scan_spirv(cut);
        if (scan.valid) {
            EXPECT_GE(n, 5u);
        }
    }
    std::mt19937 random(19);
    for (int round = 0; round < 2000; ++round) {
        std::vector<uint32_t> bent = words;
        bent[5 + random() % (bent.size() - 5)] = uint32_t(random());
        const SpirvScan scan = scan_spirv(bent);
        if (!scan.valid) {
            EXPECT_LT(scan.error_word, bent.size());
        }
    }
}

}  // namespace
}  // namespace clastrace::capture
