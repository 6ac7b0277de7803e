// SPDX-License-Identifier: Apache-2.0
// Where a reader's bytes come from: a file (pread, so memory stays bounded) or a
// caller's memory (fuzzing and mutation tests run thousands of files without disk).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

namespace clastrace::traces {

class ByteSource {
public:
    virtual ~ByteSource() = default;
    uint64_t size() const { return size_; }
    // Reads exactly n bytes at offset; false (errno in last_error()) on failure.
    // Safe to call from two threads at once (the reader reads ahead on a task).
    virtual bool read_at(uint64_t offset, size_t n, uint8_t* dst) = 0;
    virtual std::string last_error() const { return {}; }

protected:
    uint64_t size_ = 0;
};

// nullptr with *error (errno text, or why it is refused) when the file cannot be opened
// or is not a regular file.
std::unique_ptr<ByteSource> open_file_source(const std::string& path, std::string* error);
std::unique_ptr<ByteSource> memory_source(const uint8_t* data, size_t size);

}  // namespace clastrace::traces
