#include "clastrace/capture/captured_bytes_pool.h"

#include <gtest/gtest.h>

namespace clastrace::capture {
namespace {

// The pool is process-wide: each test starts by draining what earlier ones left.
void drain() {
  for (size_t size = 1; capturedBytesPooled() != 0 && size < (size_t(1) << 40); size *= 2) {
    for (int i = 0; i < 1000 && capturedBytesPooled() != 0; ++i) (void)takeCapturedBytes(size);
  }
}

TEST(CapturedBytesPool, ReturnedStorageIsReusedForARequestItFits) {
  drain();
  std::vector<uint8_t> bytes(3000, 7);
  const uint8_t* storage = bytes.data();
  recycleCapturedBytes(std::move(bytes));
  EXPECT_GE(capturedBytesPooled(), 3000u);
  std::vector<uint8_t> again = takeCapturedBytes(1500);  // 3000's class (2048) fits 1500's (2048)
  EXPECT_EQ(again.data(), storage);
  EXPECT_TRUE(again.empty());  // contents dropped
  EXPECT_GE(again.capacity(), 1500u);
  EXPECT_EQ(capturedBytesPooled(), 0u);
}

TEST(CapturedBytesPool, NeverHandsOutStorageTooSmall) {
  drain();
  recycleCapturedBytes(std::vector<uint8_t>(1000));
  for (size_t size : {1001u, 1024u, 4096u}) {
    std::vector<uint8_t> bytes = takeCapturedBytes(size);
    EXPECT_GE(bytes.capacity(), size);
  }
  EXPECT_GE(capturedBytesPooled(), 1000u);  // still there: it fitted none of them
}

TEST(CapturedBytesPool, KeepsAtMostItsLimit) {
  drain();
  const size_t big = kCapturedBytesPoolLimit / 3 + 1;
  for (int i = 0; i < 4; ++i) recycleCapturedBytes(std::vector<uint8_t>(big));
  EXPECT_LE(capturedBytesPooled(), kCapturedBytesPoolLimit);
  EXPECT_GE(capturedBytesPooled(), 2 * big);
  recycleCapturedBytes(std::vector<uint8_t>());  // nothing to keep
  drain();
  EXPECT_EQ(capturedBytesPooled(), 0u);
}

}  // namespace
}  // namespace clastrace::capture
