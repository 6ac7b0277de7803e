// SPDX-License-Identifier: Apache-2.0
#include "byte_source.h"

#include <cerrno>
#include <cstring>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace clastrace::traces {

namespace {

// Per thread: the reader's read-ahead task reads concurrently with the reader.
thread_local std::string last_read_error;

class FileSource final : public ByteSource {
public:
    FileSource(int fd, uint64_t size) : fd_(fd) { size_ = size; }
    ~FileSource() override { ::close(fd_); }

    bool read_at(uint64_t offset, size_t n, uint8_t* dst) override {
        while (n > 0) {
            ssize_t got = ::pread(fd_, dst, n, static_cast<off_t>(offset));
            if (got < 0 && errno == EINTR) continue;
            if (got <= 0) {
                last_read_error = got < 0 ? std::strerror(errno) : "unexpected end of file";
                return false;
            }
            dst += got;
            offset += static_cast<uint64_t>(got);
            n -= static_cast<size_t>(got);
        }
        return true;
    }
    std::string last_error() const override { return last_read_error; }

private:
    int fd_;
};

class MemorySource final : public ByteSource {
public:
    MemorySource(const uint8_t* data, size_t size) : data_(data) { size_ = size; }
    bool read_at(uint64_t offset, size_t n, uint8_t* dst) override {
        if (offset > size_ || n > size_ - offset) return false;
        if (n) std::memcpy(dst, data_ + offset, n);
        return true;
    }
    std::string last_error() const override { return "read past the end of the buffer"; }

private:
    const uint8_t* data_;
};

// What a path names when it is not a regular file, for the refusal.
const char* file_kind(mode_t mode) {
    if (S_ISDIR(mode)) return "a directory";
    if (S_ISFIFO(mode)) return "a FIFO or pipe";
    if (S_ISCHR(mode)) return "a character device";
    if (S_ISBLK(mode)) return "a block device";
    if (S_ISSOCK(mode)) return "a socket";
    return "neither file, directory nor device";
}

}  // namespace

std::unique_ptr<ByteSource> open_file_source(const std::string& path, std::string* error) {
    // O_NONBLOCK: opening a FIFO that has no writer would otherwise wait for one forever.
    // Regular files ignore the flag, and nothing else is read.
    int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
    if (fd < 0) {
        *error = std::strerror(errno);
        return nullptr;
    }
    struct stat st {};
    if (::fstat(fd, &st) != 0) {
        *error = std::strerror(errno);
        ::close(fd);
        return nullptr;
    }
    // A pipe, FIFO or device has no size to seek in (pread fails or /dev/zero never ends),
    // so it would be misread as an empty or endless file.
    if (!S_ISREG(st.st_mode)) {
        *error = std::string("not a regular file (") + file_kind(st.st_mode) +
                 "): clastrace reads traces from regular files";
        ::close(fd);
        return nullptr;
    }
    return std::make_unique<FileSource>(fd, static_cast<uint64_t>(st.st_size));
}

std::unique_ptr<ByteSource> memory_source(const uint8_t* data, size_t size) {
    return std::make_unique<MemorySource>(data, size);
}

}  // namespace clastrace::traces
