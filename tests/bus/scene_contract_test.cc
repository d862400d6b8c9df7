#include "bus/scene_contract.h"

#include <string>

#include <gtest/gtest.h>

namespace stackgen {
namespace {

// The id limits every consumer shares: generator ids 0..65535, seqs 0..999999998.
TEST(SceneContractTest, IdsInRange) {
  EXPECT_TRUE(SceneIdsInRange(0, 0));
  EXPECT_TRUE(SceneIdsInRange(65535, 999999998));
  EXPECT_FALSE(SceneIdsInRange(65536, 0));
  EXPECT_FALSE(SceneIdsInRange(-1, 0));
  EXPECT_FALSE(SceneIdsInRange(0, -1));
  EXPECT_FALSE(SceneIdsInRange(0, 999999999));
}

// A mask's pixels: a COCO compressed RLE string (cocoapi's rleToString) over the whole image;
// one that is empty, malformed or covers another area is refused with the reason.
TEST(SceneContractTest, MaskPixels) {
  std::string why;
  // runs 2 0s, 3 1s, 1 0 over a 6-pixel image: "2", "3", "1" each one char ('0' + n)
  EXPECT_EQ(MaskPixels("231", 6, &why), 3) << why;
  EXPECT_EQ(MaskPixels("6", 6, &why), 0) << why;
  EXPECT_EQ(MaskPixels("231", 7, &why), -1);
  EXPECT_EQ(why, "covers 6 pixels, the image has 7");
  EXPECT_EQ(MaskPixels("", 6, &why), -1);
  EXPECT_EQ(why, "is empty");
  EXPECT_EQ(MaskPixels("2\x7f", 6, &why), -1);
  EXPECT_EQ(why.rfind("is not a COCO RLE string: ", 0), 0u) << why;
  EXPECT_EQ(MaskPixels("231", 7, nullptr), -1);
}

}  // namespace
}  // namespace stackgen
