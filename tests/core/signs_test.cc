#include "bflow/core/signs.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/errors.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;

TEST(SignsTest, TextFormCharacterJIsSurfaceJ) {
  const Signs b = Signs::parse("-+-");
  EXPECT_EQ(b.size(), 3);
  EXPECT_EQ(b.bits(), 0b010u);
  EXPECT_TRUE(b.plus(1));
  EXPECT_TRUE(b.minus(0));
  EXPECT_EQ(b.sign(2), -1);
  EXPECT_EQ(b.str(), "-+-");
  EXPECT_EQ(b.with_plus(0).str(), "++-");
  EXPECT_EQ(b.with_minus(1).str(), "---");
  EXPECT_EQ(b.flipped(0b111).str(), "+-+");
  EXPECT_EQ(b.count_plus(), 1);
}

TEST(SignsTest, SixtyFourSurfaces) {
  const Signs all = Signs::all_plus(64);
  EXPECT_TRUE(all.is_all_plus());
  EXPECT_EQ(all.bits(), ~std::uint64_t{0});
  EXPECT_EQ(all.count_plus(), 64);
  EXPECT_EQ(Signs::parse(all.str()), all);
  EXPECT_TRUE(Signs::all_minus(64).is_all_minus());
}

TEST(SignsTest, RejectsBadInputWithMessage) {
  try {
    Signs::parse("-x+");
    FAIL() << "expected InvalidArgument";
  } catch (const InvalidArgument& e) {
    EXPECT_THAT(e.what(), HasSubstr("\"x\" at position 1"));
  }
  EXPECT_THROW(Signs(65), InvalidArgument);
  try {
    Signs(2, 0b100);
    FAIL() << "expected InvalidArgument";
  } catch (const InvalidArgument& e) {
    EXPECT_THAT(e.what(), HasSubstr("do not fit in 2 surfaces"));
  }
  EXPECT_THROW(Signs::parse(std::string(65, '+')), InvalidArgument);
}

}  // namespace
}  // namespace bflow
