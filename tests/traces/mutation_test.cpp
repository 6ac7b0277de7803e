// SPDX-License-Identifier: Apache-2.0
// Thousands of deterministic random mutations of a valid trace: the reader never
// crashes or hangs, and any change to the bytes is either refused or reported.
#include "exercise_reader.h"
#include "trace_test_support.h"

#include "file_format.h"

#include <gtest/gtest.h>

#include <random>

namespace clastrace::traces::testing {
namespace {

namespace f = clastrace::traces::format;

std::vector<uint64_t> chunk_offsets(const std::vector<uint8_t>& file) {
    std::vector<uint64_t> out;
    uint64_t at = f::kFileHeaderSize + f::align8(f::load<uint32_t>(file.data() + 12));
    while (at + f::kChunkHeaderSize <= file.size() &&
           f::load<uint32_t>(file.data() + at) == f::kChunkMagic) {
        out.push_back(at);
        at += f::kChunkHeaderSize + f::load<uint32_t>(file.data() + at + 20);
    }
    return out;
}

enum class Mutation { bit_flips, truncate, splice, insert_delete, length_field, count };

std::vector<uint8_t> mutate(const std::vector<uint8_t>& original,
                            const std::vector<uint64_t>& chunks, std::mt19937_64& rng,
                            Mutation kind) {
    std::vector<uint8_t> file = original;
    auto pick = [&](uint64_t n) { return n == 0 ? uint64_t{0} : rng() % n; };
    switch (kind) {
    case Mutation::bit_flips: {
        int flips = 1 + static_cast<int>(pick(8));
        for (int i = 0; i < flips; ++i)
            file[pick(file.size())] ^= static_cast<uint8_t>(1u << pick(8));
        break;
    }
    case Mutation::truncate: file.resize(pick(file.size())); break;
    case Mutation::splice: {
        uint64_t len = 1 + pick(256);
        uint64_t from = pick(file.size() - len), to = pick(file.size() - len);
        std::copy(original.begin() + static_cast<long>(from),
                  original.begin() + static_cast<long>(from + len),
                  file.begin() + static_cast<long>(to));
        break;
    }
    case Mutation::insert_delete: {
        uint64_t at = pick(file.size());
        uint64_t len = 1 + pick(64);
        if (rng() & 1) {
            file.erase(file.begin() + static_cast<long>(at),
                       file.begin() + static_cast<long>(std::min<uint64_t>(file.size(), at + len)));
        } else {
            std::vector<uint8_t> junk(len);
            for (auto& b : junk) b = static_cast<uint8_t>(rng());
            file.insert(file.begin() + static_cast<long>(at), junk.begin(), junk.end());
        }
        break;
    }
    case Mutation::length_field: {
        // A size/count field gets a hostile value; half the time its checksum is made
        // to match so the limits themselves are what must catch it.
        const uint32_t values[] = {0,           1,           0x7fffffffu,
                                   0x80000000u, 0xffffffffu, static_cast<uint32_t>(rng())};
        uint32_t v = values[pick(6)];
        if (chunks.empty() || pick(5) == 0) {
            std::memcpy(file.data() + 12, &v, 4);  // trace header size
            break;
        }
        uint64_t at = chunks[pick(chunks.size())];
        const size_t fields[] = {offsetof(f::ChunkHeader, raw_size),
                                 offsetof(f::ChunkHeader, compressed_size),
                                 offsetof(f::ChunkHeader, record_count)};
        std::memcpy(file.data() + at + fields[pick(3)], &v, 4);
        if (rng() & 1) {
            f::ChunkHeader h;
            std::memcpy(&h, file.data() + at, sizeof h);
            h.header_checksum = f::chunk_header_checksum(h);
            std::memcpy(file.data() + at, &h, sizeof h);
        }
        break;
    }
    case Mutation::count: break;
    }
    return file;
}

TEST(TraceMutation, ThousandsOfRandomMutationsAreReadOrReported) {
    const std::string path = temp_path("mutate.clt");
    write_frames_trace(path, 7, 5000);
    const std::vector<uint8_t> original = read_file(path);
    const std::vector<uint64_t> chunks = chunk_offsets(original);
    ASSERT_GE(chunks.size(), 5u);
    ExerciseResult clean = exercise_reader(original.data(), original.size());
    ASSERT_TRUE(clean.opened);
    ASSERT_EQ(clean.damage, 0u);

    std::mt19937_64 rng(20261122);
    int refused = 0, reported = 0, unchanged = 0;
    const int kMutations = 4000;
    for (int i = 0; i < kMutations; ++i) {
        auto kind = static_cast<Mutation>(i % static_cast<int>(Mutation::count));
        std::vector<uint8_t> file = mutate(original, chunks, rng, kind);
        ExerciseResult r = exercise_reader(file.data(), file.size());
        if (file == original) {
            ++unchanged;
            EXPECT_EQ(r.damage, 0u);
            continue;
        }
        if (!r.opened) {
            ++refused;
            continue;
        }
        ASSERT_GT(r.damage, 0u) << "mutation " << i << " (kind " << static_cast<int>(kind)
                                << ") went unnoticed";
        ++reported;
    }
    EXPECT_EQ(refused + reported + unchanged, kMutations);
    EXPECT_GT(reported, kMutations / 2);  // most damage is survivable, not a refusal
}

}  // namespace
}  // namespace clastrace::traces::testing
