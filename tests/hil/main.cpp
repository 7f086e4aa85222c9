#define DOCTEST_CONFIG_IMPLEMENT
#include <doctest/doctest.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include "process.hpp"

namespace {

/// On a test case's first failed assertion, the last lines of each file it
/// registered in hil::explain_files() (while its directory still exists).
struct Explain : doctest::IReporter {
  explicit Explain(const doctest::ContextOptions&) {}
  bool told = false;
  static constexpr std::size_t kLines = 40;

  void tell() {
    told = true;
    for (const hil::fs::path& f : hil::explain_files()) {
      std::ifstream in(f);
      if (!in) {
        std::cout << "(no " << f.filename().string() << ")\n";
        continue;
      }
      std::vector<std::string> tail;
      for (std::string line; std::getline(in, line);) {
        tail.push_back(std::move(line));
        if (tail.size() > kLines) tail.erase(tail.begin());
      }
      std::cout << "---- the last " << tail.size() << " lines of " << f.filename().string()
                << " ----\n";
      for (const std::string& l : tail) std::cout << l << '\n';
      std::cout << "----\n" << std::flush;
    }
  }
  void log_assert(const doctest::AssertData& ad) override {
    if (ad.m_failed && !told) tell();
  }
  void test_case_exception(const doctest::TestCaseException&) override {
    if (!told) tell();
  }
  void test_case_start(const doctest::TestCaseData&) override {
    told = false;
    hil::explain_files().clear();
  }
  void report_query(const doctest::QueryData&) override {}
  void test_run_start() override {}
  void test_run_end(const doctest::TestRunStats&) override {}
  void test_case_reenter(const doctest::TestCaseData&) override {}
  void test_case_end(const doctest::CurrentTestCaseStats&) override {}
  void subcase_start(const doctest::SubcaseSignature&) override {}
  void subcase_end() override {}
  void log_message(const doctest::MessageData&) override {}
  void test_case_skipped(const doctest::TestCaseData&) override {}
};

}  // namespace

REGISTER_LISTENER("explain", 1, Explain);

int main(int argc, char** argv) {
  const char* env = std::getenv("TURNCAL_VCAN_ENV");
  std::printf("hil tier: %s, interfaces %s and %s\n", env != nullptr ? env : "unknown",
              std::getenv("TURNCAL_HIL_IF0") ? std::getenv("TURNCAL_HIL_IF0") : "tchil0",
              std::getenv("TURNCAL_HIL_IF1") ? std::getenv("TURNCAL_HIL_IF1") : "tchil1");
  doctest::Context ctx(argc, argv);
  return ctx.run();
}
