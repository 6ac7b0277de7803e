// SPDX-License-Identifier: Apache-2.0
#include "clastrace/trace_building/engine_mirror.h"

#include <cstring>

namespace clastrace::trace_building {

void EngineMirror::add_buffer(uint64_t address, uint64_t size, uint64_t usage) {
    image_.add_region(address, size, static_cast<VkBufferUsageFlags>(usage), "mirror");
}

void EngineMirror::write(uint64_t address, const void* bytes, size_t size) {
    std::memcpy(image_.write_bytes(address, size, {}).data(), bytes, size);
}

std::vector<uint8_t> EngineMirror::read(uint64_t address, uint64_t size) const {
    const auto bytes = image_.read_bytes(address, size, {});
    const auto* p = reinterpret_cast<const uint8_t*>(bytes.data());
    return {p, p + bytes.size()};
}

engine::ExecutionRecord EngineMirror::execute(
    const VkClusterAccelerationStructureCommandsInfoNV& info) {
    engine::ExecuteOptions options;
    options.directory = &directory_;
    return engine::execute(info, image_, options);
}

}  // namespace clastrace::trace_building
