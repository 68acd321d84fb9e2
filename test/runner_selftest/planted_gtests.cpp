// One source, one planted behaviour per executable (PLANTED_<name>, CMakeLists.txt).
#include <gtest/gtest.h>

#include <cstdlib>

#if defined(PLANTED_control_passes) || defined(PLANTED_crash_after_passing_xml) || \
    defined(PLANTED_nonzero_exit_after_passing_xml)
TEST(Planted, Passes) { EXPECT_EQ(1 + 1, 2); }
#endif

#ifdef PLANTED_control_absent_data_skip
TEST(Planted, Passes) { EXPECT_EQ(1 + 1, 2); }
TEST(Planted, SkipsForAbsentData) {
  GTEST_SKIP() << "absent: /nonexistent/data (planted: a skip that names what is missing)";
}
#endif

#ifdef PLANTED_fixture_setup_fails
class PlantedFixture : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { ASSERT_TRUE(false) << "planted: the suite's set-up fails"; }
};
TEST_F(PlantedFixture, NeverReallyRuns) { EXPECT_TRUE(true); }
TEST_F(PlantedFixture, NeitherDoesThis) { EXPECT_TRUE(true); }
#endif

#ifdef PLANTED_unexplained_skip
TEST(Planted, SkipsWithoutSayingWhatIsAbsent) { GTEST_SKIP() << "planted: flaky, skipped for now"; }
#endif

int main(int argc, char** argv) {
#ifdef PLANTED_no_result_file
  (void)argc;
  (void)argv;
  return 0;  // exits cleanly without running anything or writing its result file
#else
  ::testing::InitGoogleTest(&argc, argv);
  const int rc = RUN_ALL_TESTS();
#ifdef PLANTED_crash_after_passing_xml
  std::abort();  // the passing XML is already written
#endif
#ifdef PLANTED_nonzero_exit_after_passing_xml
  return 3;
#endif
  return rc;
#endif
}
