// SPDX-License-Identifier: Apache-2.0
// The engine run on what a hand-written trace's cluster commands read, so that the writer can
// store the outputs (dst addresses, sizes, objects) a capture of that device would hold.
#pragma once

#include <clastrace/engine/execute.h>
#include <clastrace/engine/memory_image.h>
#include <clastrace/engine/object_directory.h>

#include <cstdint>
#include <vector>

namespace clastrace::trace_building {

class EngineMirror {
public:
    void add_buffer(uint64_t address, uint64_t size, uint64_t usage);
    void write(uint64_t address, const void* bytes, size_t size);
    void write(uint64_t address, const std::vector<uint8_t>& bytes) {
        write(address, bytes.data(), bytes.size());
    }
    std::vector<uint8_t> read(uint64_t address, uint64_t size) const;
    // Objects built or moved by earlier commands stay known to later ones.
    engine::ExecutionRecord execute(const VkClusterAccelerationStructureCommandsInfoNV& info);

private:
    engine::MemoryImage image_;
    engine::ObjectDirectory directory_;
};

}  // namespace clastrace::trace_building
