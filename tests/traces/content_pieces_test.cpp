// SPDX-License-Identifier: Apache-2.0
// Contents given in pieces (a snapshot merged from adjacent ranges read separately): the key,
// the stored bytes and the deduplication must be those of the same bytes given whole.
#include "trace_test_support.h"

#include <clastrace/traces/trace_reader.h>
#include <clastrace/traces/trace_writer.h>
#include <gtest/gtest.h>

#include <numeric>

namespace clastrace::traces::testing {
namespace {

std::vector<uint8_t> pattern(size_t size, uint8_t seed) {
    std::vector<uint8_t> bytes(size);
    for (size_t i = 0; i < size; ++i) bytes[i] = static_cast<uint8_t>(seed + i * 7 + (i >> 9));
    return bytes;
}

TEST(ContentPieces, SameKeyAndBytesAsWholeAndDeduplicatedAcrossCuts) {
    const std::string path = temp_path("pieces.clt");
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), {}, &e);
    ASSERT_TRUE(w) << e.message;
    // Long enough for XXH3's long-input path and streaming across its internal blocks.
    const std::vector<uint8_t> whole = pattern(5000, 3);

    uint64_t whole_key = 0;
    ASSERT_FALSE(w->add_contents(whole.data(), whole.size(), &whole_key));
    // The same bytes cut three ways (an empty piece included): the stored record is found again.
    for (std::vector<size_t> cuts :
         std::vector<std::vector<size_t>>{{1, 4999}, {240, 0, 1000, 3760}, {4999, 1}}) {
        std::vector<ContentPiece> pieces;
        size_t at = 0;
        for (size_t n : cuts) {
            pieces.push_back({whole.data() + at, n});
            at += n;
        }
        ASSERT_EQ(at, whole.size());
        uint64_t key = 0;
        ASSERT_FALSE(w->add_contents(pieces, &key));
        EXPECT_EQ(key, whole_key);
    }
    // New bytes first given in pieces get the key of the whole string, and are stored whole.
    const std::vector<uint8_t> other = pattern(3000, 99);
    const ContentPiece halves[] = {{other.data(), 1234},
                                   {other.data() + 1234, other.size() - 1234}};
    uint64_t pieces_key = 0;
    ASSERT_FALSE(w->add_contents(halves, &pieces_key));
    uint64_t again = 0;
    ASSERT_FALSE(w->add_contents(other.data(), other.size(), &again));
    EXPECT_EQ(again, pieces_key);
    EXPECT_NE(pieces_key, whole_key);

    fbs::MemorySnapshot snap;
    ASSERT_FALSE(w->snapshot(7, 16, 0x1000, halves, &snap));
    EXPECT_EQ(snap.size(), other.size());
    EXPECT_EQ(snap.hash(), pieces_key);

    const TraceWriterStats stats = w->stats();
    EXPECT_EQ(stats.contents_stored, 2u);
    EXPECT_EQ(stats.contents_deduplicated, 5u);
    ASSERT_FALSE(w->finish());

    TraceReaderOptions verify;
    verify.verify_content_keys = true;  // the reader recomputes each key from the stored bytes
    auto reader = TraceReader::open(path, &e, verify);
    ASSERT_TRUE(reader) << e.message;
    std::vector<uint8_t> back;
    ASSERT_FALSE(reader->read_contents(pieces_key, &back));
    EXPECT_EQ(back, other);
    ASSERT_FALSE(reader->read_contents(whole_key, &back));
    EXPECT_EQ(back, whole);
    EXPECT_TRUE(reader->damage().empty());
}

}  // namespace
}  // namespace clastrace::traces::testing
