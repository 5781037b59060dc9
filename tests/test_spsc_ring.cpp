// The pipeline's single-producer single-consumer ring: order, bounds, the
// producer's take-back, blocking waits and their stop, and two threads
// hammering it (run under ASan+UBSan by tools/run-tests.sh).

#include "markerd/daemon/spsc_ring.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <stop_token>
#include <thread>
#include <vector>

namespace markerd::daemon {
namespace {

TEST(SpscRing, CapacityIsRoundedUpToAPowerOfTwo) {
  EXPECT_EQ(SpscRing<int>(1).capacity(), 1U);
  EXPECT_EQ(SpscRing<int>(5).capacity(), 8U);
  EXPECT_EQ(SpscRing<int>(64).capacity(), 64U);
  EXPECT_THROW(SpscRing<int>(0), std::invalid_argument);
}

TEST(SpscRing, IsFirstInFirstOutAndBounded) {
  SpscRing<int> ring(4);
  EXPECT_FALSE(ring.try_pop().has_value());
  for (int v = 1; v <= 4; ++v) EXPECT_TRUE(ring.try_push(v));
  EXPECT_TRUE(ring.full());
  EXPECT_FALSE(ring.try_push(5));
  EXPECT_EQ(ring.size(), 4U);
  for (int v = 1; v <= 4; ++v) EXPECT_EQ(ring.try_pop(), std::optional<int>(v));
  EXPECT_FALSE(ring.try_pop().has_value());
  EXPECT_EQ(ring.size(), 0U);
}

TEST(SpscRing, KeepsOrderOverManyLaps) {
  SpscRing<std::uint32_t> ring(4);
  std::uint32_t pushed = 1;
  std::uint32_t popped = 1;
  // Uneven bursts move the positions across the slot boundary in every phase.
  for (int round = 0; round < 1000; ++round) {
    for (int k = 0; k < 1 + round % 4 && ring.try_push(pushed); ++k) ++pushed;
    for (int k = 0; k < 1 + (round * 7) % 4; ++k) {
      const auto v = ring.try_pop();
      if (!v) break;
      ASSERT_EQ(*v, popped);
      ++popped;
    }
  }
  while (const auto v = ring.try_pop()) EXPECT_EQ(*v, popped++);
  EXPECT_EQ(popped, pushed);
}

TEST(SpscRing, TakeBackLeavesAVacancyInPlace) {
  SpscRing<int> ring(8);
  for (int v = 1; v <= 4; ++v) ASSERT_TRUE(ring.try_push(v));
  EXPECT_EQ(ring.oldest_waiting(), 1);
  EXPECT_TRUE(ring.take_back(1));
  EXPECT_TRUE(ring.take_back(3));
  EXPECT_FALSE(ring.take_back(3)) << "taken back once only";
  EXPECT_EQ(ring.oldest_waiting(), 2) << "vacancies are skipped";
  EXPECT_EQ(ring.size(), 4U) << "a vacancy keeps its place";
  EXPECT_EQ(ring.try_pop(), std::optional<int>(0));
  EXPECT_EQ(ring.try_pop(), std::optional<int>(2));
  EXPECT_FALSE(ring.take_back(2)) << "a popped item cannot be taken back";
  EXPECT_EQ(ring.try_pop(), std::optional<int>(0));
  EXPECT_EQ(ring.try_pop(), std::optional<int>(4));
  EXPECT_EQ(ring.oldest_waiting(), 0);
}

// Every value arrives once and in order through a small ring, so that both
// sides keep running into the full and the empty ring and sleep.
TEST(SpscRing, TwoThreadsPassMillionsOfValuesInOrder) {
  constexpr std::uint64_t kCount = 2'000'000;
  SpscRing<std::uint64_t> ring(64);
  std::uint64_t received = 0;
  std::uint64_t out_of_order = 0;
  std::jthread consumer([&](const std::stop_token& stop) {
    std::uint64_t expected = 1;
    while (expected <= kCount) {
      if (const auto v = ring.try_pop()) {
        if (*v != expected) ++out_of_order;
        expected = *v + 1;
        ++received;
      } else if (!ring.wait_for_item(stop)) {
        return;
      }
    }
  });
  const std::stop_token never;
  for (std::uint64_t v = 1; v <= kCount; ++v) ASSERT_TRUE(ring.push(v, never));
  consumer.join();
  EXPECT_EQ(received, kCount);
  EXPECT_EQ(out_of_order, 0U);
  EXPECT_EQ(ring.size(), 0U);
}

// The producer takes back the oldest waiting value while the consumer pops:
// each value ends on exactly one side, the consumer's in order, and every
// position arrives (vacancies included).
TEST(SpscRing, TakeBackRacesPopWithoutLosingOrDoublingValues) {
  constexpr std::uint32_t kCount = 1'000'000;
  SpscRing<std::uint32_t> ring(16);
  std::vector<std::uint8_t> seen(kCount + 1, 0);  // 1: popped, 2: taken back
  std::uint64_t positions = 0;
  std::uint64_t out_of_order = 0;
  std::jthread consumer([&](const std::stop_token& stop) {
    std::uint32_t last = 0;
    for (;;) {
      if (const auto v = ring.try_pop()) {
        ++positions;
        if (*v == 0) continue;
        if (*v <= last) ++out_of_order;
        last = *v;
        ++seen[*v];
      } else if (!ring.wait_for_item(stop)) {
        while (const auto rest = ring.try_pop()) {
          ++positions;
          if (*rest != 0) ++seen[*rest];
        }
        return;
      }
    }
  });
  const std::stop_token never;
  std::uint32_t taken_back = 0;
  for (std::uint32_t v = 1; v <= kCount; ++v) {
    ASSERT_TRUE(ring.push(v, never));
    if (v % 3 == 0) {
      const std::uint32_t oldest = ring.oldest_waiting();
      if (oldest != 0 && ring.take_back(oldest)) {
        seen[oldest] += 2;  // the consumer never writes this entry: it did not get the value
        ++taken_back;
      }
    }
  }
  consumer.request_stop();
  consumer.join();
  EXPECT_EQ(positions, kCount);
  EXPECT_EQ(out_of_order, 0U);
  EXPECT_GT(taken_back, 0U);
  std::uint32_t popped = 0;
  for (std::uint32_t v = 1; v <= kCount; ++v) {
    ASSERT_TRUE(seen[v] == 1 || seen[v] == 2) << "value " << v << " state " << int(seen[v]);
    popped += seen[v] == 1 ? 1 : 0;
  }
  EXPECT_EQ(popped + taken_back, kCount);
}

TEST(SpscRing, AStopRequestEndsAConsumersWait) {
  SpscRing<int> ring(4);
  bool woke_empty = false;
  std::jthread consumer([&](const std::stop_token& stop) { woke_empty = !ring.wait_for_item(stop); });
  consumer.request_stop();
  consumer.join();
  EXPECT_TRUE(woke_empty);
}

TEST(SpscRing, AStopRequestEndsAProducersWaitForRoom) {
  SpscRing<int> ring(2);
  ASSERT_TRUE(ring.try_push(1));
  ASSERT_TRUE(ring.try_push(2));
  bool pushed = true;
  std::jthread producer([&](const std::stop_token& stop) { pushed = ring.push(3, stop); });
  producer.request_stop();
  producer.join();
  EXPECT_FALSE(pushed);
  EXPECT_EQ(ring.size(), 2U);
}

TEST(SpscRing, AProducerWaitingForRoomGoesOnWhenTheConsumerPops) {
  SpscRing<int> ring(1);
  ASSERT_TRUE(ring.try_push(1));
  bool pushed = false;
  std::jthread producer([&](const std::stop_token& stop) { pushed = ring.push(2, stop); });
  // Whether the producer is asleep yet or not, the pop makes room for it.
  EXPECT_EQ(ring.try_pop(), std::optional<int>(1));
  producer.join();
  EXPECT_TRUE(pushed);
  EXPECT_EQ(ring.try_pop(), std::optional<int>(2));
}

TEST(SpscRing, ATimedWaitEndsAtItsDeadlineWhenNothingComes) {
  SpscRing<int> ring(4);
  const auto start = std::chrono::steady_clock::now();
  EXPECT_FALSE(ring.wait_for_item_until({}, start + std::chrono::milliseconds(30)));
  EXPECT_GE(std::chrono::steady_clock::now() - start, std::chrono::milliseconds(30));
  // A deadline already past returns at once, and an item is seen without waiting.
  EXPECT_FALSE(ring.wait_for_item_until({}, start));
  ASSERT_TRUE(ring.try_push(7));
  EXPECT_TRUE(ring.wait_for_item_until({}, start));
}

TEST(SpscRing, ATimedWaitWakesForAnItemLongBeforeItsDeadline) {
  SpscRing<int> ring(4);
  std::chrono::steady_clock::duration waited{};
  std::jthread consumer([&](const std::stop_token& stop) {
    const auto start = std::chrono::steady_clock::now();
    EXPECT_TRUE(ring.wait_for_item_until(stop, start + std::chrono::seconds(60)));
    waited = std::chrono::steady_clock::now() - start;
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(20));  // likely asleep by now; either way it must wake
  ASSERT_TRUE(ring.try_push(1));
  consumer.join();
  EXPECT_LT(waited, std::chrono::seconds(30));
}

TEST(SpscRing, AStopRequestEndsATimedWait) {
  SpscRing<int> ring(4);
  bool got_item = true;
  std::jthread consumer([&](const std::stop_token& stop) {
    got_item = ring.wait_for_item_until(stop, std::chrono::steady_clock::now() + std::chrono::seconds(60));
  });
  consumer.request_stop();
  consumer.join();
  EXPECT_FALSE(got_item);
}

}  // namespace
}  // namespace markerd::daemon
