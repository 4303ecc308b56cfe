#include "mesh/vector_room.h"

#include <gtest/gtest.h>

#include <cstddef>
#include <vector>

namespace tetcosim {
namespace {

// A count that creeps up by one from 1 to 10,000 (contacts, step by step),
// each time assigned anew (std::vector's assign reallocates to exactly the
// count at every new high) or resized from empty: with room, the vector
// reallocates about log2(10,000) = 14 times. Shrinking keeps the room.
TEST(VectorRoom, ACountCreepingUpReallocatesLogarithmicallyOften) {
  for (const bool resize : {false, true}) {
    std::vector<int> v;
    int reallocations = 0;
    for (std::size_t n = 1; n <= 10000; ++n) {
      const std::size_t capacity = v.capacity();
      if (resize) {
        v.clear();  // (a step's count starts from nothing)
        ResizeWithRoom(v, n);
      } else {
        AssignWithRoom(v, n, 7);
      }
      ASSERT_EQ(v.size(), n);
      if (!resize) {
        ASSERT_EQ(v.back(), 7);
      }
      reallocations += v.capacity() != capacity;
    }
    EXPECT_LE(reallocations, 15) << (resize ? "resize" : "assign");
    const std::size_t capacity = v.capacity();
    AssignWithRoom(v, 10, 1);
    EXPECT_EQ(v.capacity(), capacity);
  }
}

}  // namespace
}  // namespace tetcosim
