// SPDX-License-Identifier: Apache-2.0
#include "content_hash.h"

namespace clastrace::traces {
namespace {

struct KernelTable {
    ContentHashKernel kernels[3];
    size_t count = 0;

    KernelTable() {
        kernels[count++] = {"baseline", detail::hash_content_baseline,
                            detail::content_key_baseline};
#if defined(CLASTRACE_CONTENT_HASH_X86)
        __builtin_cpu_init();  // (its checks include the OS saving the wider registers)
        if (__builtin_cpu_supports("avx2"))
            kernels[count++] = {"avx2", detail::hash_content_avx2, detail::content_key_avx2};
        if (__builtin_cpu_supports("avx512f"))
            kernels[count++] = {"avx512", detail::hash_content_avx512, detail::content_key_avx512};
#endif
    }
};

const KernelTable& table() {
    static const KernelTable kT;
    return kT;
}

}  // namespace

const ContentHashKernel* content_hash_kernels(size_t* count) {
    *count = table().count;
    return table().kernels;
}

ContentHashes hash_content(const ContentPiece* pieces, size_t count) {
    static const auto kHash = table().kernels[table().count - 1].hash;
    return kHash(pieces, count);
}

uint64_t content_key_of(const ContentPiece* pieces, size_t count, uint64_t seed) {
    static const auto kEy = table().kernels[table().count - 1].key;
    return kEy(pieces, count, seed);
}

}  // namespace clastrace::traces
