#include "gen/randomize/background.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

namespace stackgen {
namespace {

using Kind = config::BackgroundConfig::Kind;
namespace fs = std::filesystem;

constexpr Kind kGenerated[] = {config::BackgroundConfig::PLAIN, config::BackgroundConfig::NOISE,
                               config::BackgroundConfig::STRIPES,
                               config::BackgroundConfig::CHECKER};

config::BackgroundConfig OnlyKind(Kind kind) {
  config::BackgroundConfig config;
  config.add_kind(kind);
  return config;
}

// the distinct colours of an RGB image.
std::set<std::tuple<int, int, int>> Colours(const cv::Mat& image) {
  std::set<std::tuple<int, int, int>> colours;
  for (int y = 0; y < image.rows; ++y) {
    for (int x = 0; x < image.cols; ++x) {
      const cv::Vec3b& p = image.at<cv::Vec3b>(y, x);
      colours.insert({p[0], p[1], p[2]});
    }
  }
  return colours;
}

// the largest difference of a channel between horizontally or vertically adjacent pixels.
int LargestStep(const cv::Mat& image) {
  cv::Mat dx;
  cv::Mat dy;
  cv::absdiff(image.colRange(1, image.cols), image.colRange(0, image.cols - 1), dx);
  cv::absdiff(image.rowRange(1, image.rows), image.rowRange(0, image.rows - 1), dy);
  double max_x = 0;
  double max_y = 0;
  cv::minMaxLoc(dx.reshape(1), nullptr, &max_x);
  cv::minMaxLoc(dy.reshape(1), nullptr, &max_y);
  return static_cast<int>(std::max(max_x, max_y));
}

// a temporary folder, removed at the end of the test.
class TempDir {
 public:
  explicit TempDir(const std::string& name)
      : path_(fs::temp_directory_path() /
              ("stackgen_background_test_" + name + "_" + std::to_string(getpid()))) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  std::string path() const { return path_.string(); }
  std::string File(const std::string& name) const { return (path_ / name).string(); }

 private:
  fs::path path_;
};

// a folder with two PNGs (a wide red-to-yellow gradient, a tall solid blue one) and a file
// OpenCV cannot read.
class ImageFolder : public TempDir {
 public:
  ImageFolder() : TempDir("images") {
    // OpenCV writes BGR: (b, g, r).
    cv::Mat gradient(200, 300, CV_8UC3);
    for (int y = 0; y < gradient.rows; ++y) {
      for (int x = 0; x < gradient.cols; ++x) {
        gradient.at<cv::Vec3b>(y, x) = cv::Vec3b(10, static_cast<uchar>(10 + x * 200 / 300), 250);
      }
    }
    cv::imwrite(File("a_gradient.png"), gradient);
    cv::imwrite(File("b_blue.png"), cv::Mat(400, 40, CV_8UC3, cv::Scalar(240, 20, 30)));
    std::ofstream(File("c_notes.txt")) << "not an image\n";
  }
};

// every kind alone gives a CV_8UC3 image of the asked size (odd sizes too) and reports its kind.
TEST(BackgroundTest, EachKindAloneHasTheRightSize) {
  const ImageFolder folder;
  std::mt19937_64 engine(1);
  for (const Kind only : {config::BackgroundConfig::PLAIN, config::BackgroundConfig::NOISE,
                          config::BackgroundConfig::STRIPES, config::BackgroundConfig::CHECKER,
                          config::BackgroundConfig::IMAGE}) {
    const BackgroundSource source(OnlyKind(only), folder.path());
    for (const cv::Size size : {cv::Size(640, 480), cv::Size(101, 37), cv::Size(1626, 1236)}) {
      Kind kind = config::BackgroundConfig::KIND_UNSPECIFIED;
      const cv::Mat image = source.Draw(size.width, size.height, engine, &kind);
      EXPECT_EQ(image.size(), size) << only;
      EXPECT_EQ(image.type(), CV_8UC3) << only;
      EXPECT_EQ(kind, only);
    }
  }
}

// PLAIN is one colour, every channel in [min, max] * 255, and the colours vary between draws.
TEST(BackgroundTest, PlainIsUniformWithinRange) {
  config::BackgroundConfig config = OnlyKind(config::BackgroundConfig::PLAIN);
  config.set_min(0.2);
  config.set_max(0.4);
  const BackgroundSource source(config, "");
  std::mt19937_64 engine(2);
  std::set<std::tuple<int, int, int>> seen;
  for (int i = 0; i < 50; ++i) {
    const cv::Mat image = source.Draw(64, 48, engine);
    const std::set<std::tuple<int, int, int>> colours = Colours(image);
    ASSERT_EQ(colours.size(), 1u);
    const auto [r, g, b] = *colours.begin();
    for (const int channel : {r, g, b}) {
      EXPECT_GE(channel, 51);
      EXPECT_LE(channel, 102);
    }
    seen.insert(*colours.begin());
  }
  EXPECT_GT(seen.size(), 40u);
}

// STRIPES and CHECKER hold exactly two colours (no antialiasing), each over a fair share of the
// image.
TEST(BackgroundTest, StripesAndCheckerHaveExactlyTwoColours) {
  std::mt19937_64 engine(3);
  for (const Kind kind : {config::BackgroundConfig::STRIPES, config::BackgroundConfig::CHECKER}) {
    const BackgroundSource source(OnlyKind(kind), "");
    for (int i = 0; i < 20; ++i) {
      const cv::Mat image = source.Draw(640, 480, engine);
      const std::set<std::tuple<int, int, int>> colours = Colours(image);
      ASSERT_EQ(colours.size(), 2u) << kind;
      const auto [r, g, b] = *colours.begin();
      cv::Mat first;
      cv::inRange(image, cv::Scalar(r, g, b), cv::Scalar(r, g, b), first);
      const double share = cv::countNonZero(first) / static_cast<double>(image.total());
      EXPECT_GT(share, 0.25) << kind;
      EXPECT_LT(share, 0.75) << kind;
    }
  }
}

// NOISE is smooth (adjacent pixels differ by a few levels; its finest octave has a period of
// at least 8 px, so small frames are steeper) yet varies over the image, while STRIPES, by the
// same measure, is not smooth.
TEST(BackgroundTest, NoiseIsSmoothButVaries) {
  const BackgroundSource noise(OnlyKind(config::BackgroundConfig::NOISE), "");
  std::mt19937_64 engine(4);
  for (const auto& [size, largest_step] :
       {std::pair{cv::Size(640, 480), 12}, std::pair{cv::Size(1626, 1236), 12},
        std::pair{cv::Size(200, 100), 24}}) {
    for (int i = 0; i < 10; ++i) {
      const cv::Mat image = noise.Draw(size.width, size.height, engine);
      EXPECT_LE(LargestStep(image), largest_step) << size;
      // varies: the channel where the two drawn colours differ most spans at least 10 levels,
      // and its values spread over that span (the field is not flat with a few outliers).
      double span = 0;
      cv::Mat widest;
      for (int c = 0; c < 3; ++c) {
        cv::Mat channel;
        cv::extractChannel(image, channel, c);
        double lo = 0;
        double hi = 0;
        cv::minMaxLoc(channel, &lo, &hi);
        if (hi - lo > span) {
          span = hi - lo;
          channel.convertTo(widest, CV_64F, 1 / (hi - lo), -lo / (hi - lo));
        }
      }
      ASSERT_GE(span, 10) << size;
      cv::Scalar mean;
      cv::Scalar stddev;
      cv::meanStdDev(widest, mean, stddev);
      EXPECT_GT(stddev[0], 0.1) << size;
    }
  }
  const BackgroundSource stripes(OnlyKind(config::BackgroundConfig::STRIPES), "");
  EXPECT_GT(LargestStep(stripes.Draw(640, 480, engine)), 12);
}

// IMAGE lists the folder's readable images in name order, skipping the text file; a drawn image
// covers the frame (no unfilled pixel: both sources have no channel below 10) in RGB order, and
// is scaled keeping the aspect ratio: the 300 x 200 gradient (green 10 + 200 x / 300 along x) in
// a 4:3 frame is cropped to about 267 of its 300 columns, so green spans about 178 levels along
// x and is constant down each column (stretching it would span 200).
TEST(BackgroundTest, ImageCoversTheFrame) {
  const ImageFolder folder;
  const BackgroundSource source(OnlyKind(config::BackgroundConfig::IMAGE), folder.path());
  ASSERT_EQ(source.image_paths().size(), 2u);
  EXPECT_EQ(source.image_paths()[0], folder.File("a_gradient.png"));
  EXPECT_EQ(source.image_paths()[1], folder.File("b_blue.png"));
  std::mt19937_64 engine(5);
  for (const cv::Size size : {cv::Size(640, 480), cv::Size(64, 48)}) {
    int red = 0;
    int blue = 0;
    for (int i = 0; i < 40; ++i) {
      const cv::Mat image = source.Draw(size.width, size.height, engine);
      double min_value = 0;
      cv::minMaxLoc(image.reshape(1), &min_value);
      EXPECT_GE(min_value, 9) << size;
      const cv::Scalar mean = cv::mean(image);
      if (mean[2] > 200 && mean[0] < 60) ++blue;  // the solid: r 30, b 240
      if (!(mean[0] > 200 && mean[2] < 40)) continue;
      ++red;  // the gradient: r 250, b 10
      cv::Mat green;
      cv::extractChannel(image, green, 1);
      const int span = green.at<uchar>(0, size.width - 1) - green.at<uchar>(0, 0);
      EXPECT_GE(span, 172) << size;
      EXPECT_LE(span, 182) << size;
      for (int x = 0; x < size.width; x += 7) {
        double lo = 0;
        double hi = 0;
        cv::minMaxLoc(green.col(x), &lo, &hi);
        EXPECT_LE(hi - lo, 1) << size << " column " << x;
      }
    }
    EXPECT_GT(red, 5) << size;
    EXPECT_GT(blue, 5) << size;
    EXPECT_EQ(red + blue, 40) << size;
  }
}

// a folder with no readable image, a missing folder, or an empty image_dir with IMAGE listed
// throw, naming background.image_dir and the folder.
TEST(BackgroundTest, FolderWithoutImagesThrows) {
  const TempDir empty("empty");
  std::ofstream(empty.File("readme.txt")) << "no images here\n";
  std::ofstream(empty.File("broken.png")) << "\x89PNG but not really";
  for (const std::string& folder : {empty.path(), empty.File("missing")}) {
    try {
      BackgroundSource source(OnlyKind(config::BackgroundConfig::IMAGE), folder);
      ADD_FAILURE() << "no throw for " << folder;
    } catch (const std::runtime_error& error) {
      const std::string message = error.what();
      EXPECT_NE(message.find("background.image_dir"), std::string::npos) << message;
      EXPECT_NE(message.find("'" + folder + "'"), std::string::npos) << message;
    }
  }
  EXPECT_THROW(BackgroundSource(OnlyKind(config::BackgroundConfig::IMAGE), ""), std::runtime_error);
  // without IMAGE among the kinds the folder is not looked at.
  EXPECT_NO_THROW(BackgroundSource(OnlyKind(config::BackgroundConfig::PLAIN), empty.path()));
}

// the same seed gives the same image for every kind, another seed another image, and every
// draw takes exactly two values from the engine.
TEST(BackgroundTest, SameSeedSameImage) {
  const ImageFolder folder;
  for (const Kind only : {config::BackgroundConfig::PLAIN, config::BackgroundConfig::NOISE,
                          config::BackgroundConfig::STRIPES, config::BackgroundConfig::CHECKER,
                          config::BackgroundConfig::IMAGE}) {
    const BackgroundSource source(OnlyKind(only), folder.path());
    std::mt19937_64 a(42);
    std::mt19937_64 b(42);
    std::mt19937_64 other(43);
    const cv::Mat first = source.Draw(320, 240, a);
    EXPECT_EQ(cv::norm(first, source.Draw(320, 240, b), cv::NORM_INF), 0) << only;
    EXPECT_GT(cv::norm(first, source.Draw(320, 240, other), cv::NORM_INF), 0) << only;
    std::mt19937_64 reference(42);
    reference.discard(2);
    EXPECT_EQ(a, reference) << only;
  }
}

// the default kinds are the four generated ones, plus IMAGE with an image_dir; over 500 draws
// each is drawn about equally often.
TEST(BackgroundTest, DefaultKindsHitEveryKind) {
  EXPECT_EQ(BackgroundSource(config::BackgroundConfig(), "").kinds(),
            std::vector<Kind>(std::begin(kGenerated), std::end(kGenerated)));
  const ImageFolder folder;
  config::BackgroundConfig config;
  config.set_image_dir("images");
  const BackgroundSource source(config, folder.path());
  ASSERT_EQ(source.kinds().size(), 5u);
  std::mt19937_64 engine(6);
  std::map<Kind, int> counts;
  for (int i = 0; i < 500; ++i) {
    Kind kind = config::BackgroundConfig::KIND_UNSPECIFIED;
    source.Draw(32, 24, engine, &kind);
    ++counts[kind];
  }
  ASSERT_EQ(counts.size(), 5u);
  for (const auto& [kind, count] : counts) {
    EXPECT_GT(count, 70) << kind;
    EXPECT_LT(count, 130) << kind;
  }
}

}  // namespace
}  // namespace stackgen
