// SPDX-License-Identifier: Apache-2.0
#include "clastrace/traces/output_file.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>

namespace clastrace::traces {

namespace {

constexpr int kMaxLinks = 40;  // as the kernel's own limit on links followed in one lookup

std::string system_reason(int err) { return std::strerror(err); }

std::string directory_of(const std::string& path) {
    const size_t slash = path.rfind('/');
    if (slash == std::string::npos) return ".";
    if (slash == 0) return "/";
    return path.substr(0, slash);
}

// "cannot write 'PATH': ", naming the link's target too where PATH is a symbolic link.
std::string cannot_write(const std::string& path, const std::string& target_path) {
    if (target_path == path) return "cannot write '" + path + "': ";
    return "cannot write '" + path + "' (-> '" + target_path + "'): ";
}

bool fail(std::string* error, const std::string& message) {
    if (error) *error = message;
    return false;
}

bool write_all(int fd, std::string_view bytes) {
    while (!bytes.empty()) {
        const ssize_t n = ::write(fd, bytes.data(), bytes.size());
        if (n < 0 && errno == EINTR) continue;
        if (n < 0) return false;
        if (n == 0) {
            errno = EIO;
            return false;
        }
        bytes.remove_prefix(static_cast<size_t>(n));
    }
    return true;
}

// Opens a device or FIFO for writing in place. A FIFO is opened without blocking (a missing
// reader is an error, not a wait), then switched back to blocking writes.
int open_special(const OutputTarget& target) {
    const int flags = O_WRONLY | O_CLOEXEC | (target.kind == OutputKind::kFifo ? O_NONBLOCK : 0);
    const int fd = ::open(target.path.c_str(), flags);
    if (fd >= 0 && target.kind == OutputKind::kFifo)
        ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) & ~O_NONBLOCK);
    return fd;
}

std::string open_failure(const std::string& named, const OutputTarget& target, int err) {
    if (target.kind == OutputKind::kFifo && err == ENXIO)
        return named + "no process is reading this FIFO";
    return named + system_reason(err);
}

// Only a lock held elsewhere refuses: where the file system has no flock (ENOLCK), the output
// is written unguarded rather than not at all.
bool lock_exclusive(int fd, const std::string& named, std::string* error) {
    while (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
        if (errno == EINTR) continue;
        if (errno == EWOULDBLOCK) {
            return fail(error,
                        named +
                            "another process (another capture?) is writing it and holds its lock");
        }
        return true;
    }
    return true;
}

// A temporary file beside `target`, created with the mode a new file gets (umask applied).
int create_temporary(const std::string& target, std::string* temporary) {
    static std::atomic<unsigned> counter{0};
    const std::string dir = directory_of(target);
    const size_t slash = target.rfind('/');
    const std::string base = slash == std::string::npos ? target : target.substr(slash + 1);
    for (int attempt = 0; attempt < 100; ++attempt) {
        *temporary = dir + "/." + base + ".clastrace-" + std::to_string(::getpid()) + "-" +
                     std::to_string(counter.fetch_add(1)) + ".tmp";
        const int fd = ::open(temporary->c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
        if (fd >= 0 || errno != EEXIST) return fd;
    }
    errno = EEXIST;
    return -1;
}

bool replace_by_rename(const std::string& path, const OutputTarget& target, std::string_view bytes,
                       std::string* error) {
    const std::string named = cannot_write(path, target.path);
    std::string temporary;
    const int fd = create_temporary(target.path, &temporary);
    if (fd < 0)
        return fail(error, named + "cannot create a file beside it: " + system_reason(errno));
    struct stat existing {};
    if (target.kind == OutputKind::kRegular && ::stat(target.path.c_str(), &existing) == 0) {
        ::fchmod(fd, existing.st_mode & 07777);  // the replacement keeps the file's permissions
    }
    const bool written = write_all(fd, bytes);
    const int write_errno = errno;
    if (::close(fd) != 0 || !written) {
        const int err = written ? errno : write_errno;
        ::unlink(temporary.c_str());
        return fail(error, named + "write failed: " + system_reason(err));
    }
    if (::rename(temporary.c_str(), target.path.c_str()) != 0) {
        const int err = errno;
        ::unlink(temporary.c_str());
        return fail(error, named + "cannot rename the new file over it: " + system_reason(err));
    }
    return true;
}

}  // namespace

const char* output_kind_name(OutputKind kind) {
    switch (kind) {
    case OutputKind::kAbsent: return "new file";
    case OutputKind::kRegular: return "regular file";
    case OutputKind::kCharacterDevice: return "character device";
    case OutputKind::kFifo: return "FIFO";
    }
    return "file";
}

bool resolve_output(const std::string& path, OutputTarget* target, std::string* error) {
    if (path.empty()) return fail(error, "cannot write '': the output's name is empty");
    std::string current = path;
    for (int links = 0; links <= kMaxLinks; ++links) {
        struct stat st {};
        if (::lstat(current.c_str(), &st) != 0) {
            if (errno != ENOENT)
                return fail(error, cannot_write(path, current) + system_reason(errno));
            *target = {current, OutputKind::kAbsent};
            return true;
        }
        if (S_ISLNK(st.st_mode)) {
            std::string link(static_cast<size_t>(st.st_size > 0 ? st.st_size : 4096) + 1, '\0');
            const ssize_t n = ::readlink(current.c_str(), link.data(), link.size());
            if (n < 0)
                return fail(error, cannot_write(path, current) +
                                       "cannot read the link: " + system_reason(errno));
            link.resize(static_cast<size_t>(n));
            current = link.front() == '/' ? link : directory_of(current) + "/" + link;
            continue;
        }
        const std::string named = cannot_write(path, current);
        if (S_ISREG(st.st_mode))
            *target = {current, OutputKind::kRegular};
        else if (S_ISCHR(st.st_mode))
            *target = {current, OutputKind::kCharacterDevice};
        else if (S_ISFIFO(st.st_mode))
            *target = {current, OutputKind::kFifo};
        else if (S_ISDIR(st.st_mode))
            return fail(error, named + "it is a directory");
        else if (S_ISBLK(st.st_mode))
            return fail(error,
                        named + "it is a block device (clastrace writes no output onto one)");
        else if (S_ISSOCK(st.st_mode))
            return fail(error, named + "it is a socket (clastrace writes no output onto one)");
        else
            return fail(error, named + "it is not a file, device or FIFO");
        return true;
    }
    return fail(error, cannot_write(path, path) + system_reason(ELOOP));
}

bool probe_output(const std::string& path, std::string* error) {
    OutputTarget target;
    if (!resolve_output(path, &target, error)) return false;
    const std::string named = cannot_write(path, target.path);
    if (target.kind == OutputKind::kCharacterDevice || target.kind == OutputKind::kFifo) {
        if (::access(target.path.c_str(), W_OK) != 0)
            return fail(error, named + system_reason(errno));
        return true;
    }
    const std::string dir = directory_of(target.path);
    if (::access(dir.c_str(), W_OK | X_OK) != 0) {
        return fail(error, named + system_reason(errno));
    }
    return true;
}

bool write_output_file(const std::string& path, std::string_view bytes, std::string* error) {
    OutputTarget target;
    if (!resolve_output(path, &target, error)) return false;
    if (target.kind == OutputKind::kAbsent || target.kind == OutputKind::kRegular) {
        return replace_by_rename(path, target, bytes, error);
    }
    const std::string named = cannot_write(path, target.path);
    const int fd = open_special(target);
    if (fd < 0) return fail(error, open_failure(named, target, errno));
    const bool written = write_all(fd, bytes);
    const int write_errno = errno;
    if (::close(fd) != 0 || !written) {
        return fail(error, named + "write failed: " + system_reason(written ? errno : write_errno));
    }
    return true;
}

int open_output_in_place(const std::string& path, OutputTarget* target, std::string* error) {
    if (!resolve_output(path, target, error)) return -1;
    const std::string named = cannot_write(path, target->path);
    if (target->kind == OutputKind::kCharacterDevice || target->kind == OutputKind::kFifo) {
        const int fd = open_special(*target);
        if (fd < 0) fail(error, open_failure(named, *target, errno));
        return fd;
    }
    // No O_TRUNC: the earlier file is emptied only once the lock is held and the new content
    // is about to be written (start_output_in_place). O_NOFOLLOW: the target was resolved.
    const int fd = ::open(target->path.c_str(), O_WRONLY | O_CREAT | O_NOFOLLOW | O_CLOEXEC, 0644);
    if (fd < 0) {
        fail(error, open_failure(named, *target, errno));
        return -1;
    }
    if (!lock_exclusive(fd, named, error)) {
        ::close(fd);
        return -1;
    }
    return fd;
}

int adopt_output(int fd, const std::string& path, OutputTarget* target, std::string* error) {
    if (!resolve_output(path, target, error)) return -1;
    const std::string named = cannot_write(path, target->path);
    struct stat held {
    }, named_stat{};
    const int access_mode = ::fcntl(fd, F_GETFL);
    if (access_mode < 0 ||
        ((access_mode & O_ACCMODE) != O_WRONLY && (access_mode & O_ACCMODE) != O_RDWR) ||
        ::fstat(fd, &held) != 0 || ::stat(target->path.c_str(), &named_stat) != 0 ||
        held.st_dev != named_stat.st_dev || held.st_ino != named_stat.st_ino) {
        fail(error, named + "descriptor " + std::to_string(fd) +
                        " handed down for it is not this file open for writing");
        return -1;
    }
    if (target->kind == OutputKind::kRegular && !lock_exclusive(fd, named, error)) return -1;
    ::fcntl(fd, F_SETFD, FD_CLOEXEC);  // the application's own children do not inherit it
    return fd;
}

bool start_output_in_place(int fd, const std::string& path, std::string* error) {
    struct stat st {};
    if (::fstat(fd, &st) != 0) return fail(error, cannot_write(path, path) + system_reason(errno));
    if (!S_ISREG(st.st_mode)) return true;
    if (::ftruncate(fd, 0) != 0 || ::lseek(fd, 0, SEEK_SET) != 0) {
        return fail(error, cannot_write(path, path) +
                               "cannot empty the earlier file: " + system_reason(errno));
    }
    return true;
}

}  // namespace clastrace::traces
