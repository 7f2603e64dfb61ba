// `ecat man` and `ecat completion bash`: generated from the command definitions, so every
// subcommand and its options are in both.
#include <string>

#include <gtest/gtest.h>

#include "support/tool_runner.hpp"

namespace ecat::test {
namespace {

TEST(DocsTool, ManPageListsEveryCommandWithItsOptions) {
  ToolRunner tool("man");
  const auto r = tool.run("man");
  ASSERT_EQ(r.status, 0) << r.err;
  for (const char* needle :
       {".TH ECAT 1", ".SH NAME", ".SH SYNOPSIS", ".SH COMMANDS", ".SS upload", ".SS serve",
        ".SS foe_write", ".SH EXIT STATUS", "\\-\\-attach", "\\-\\-complete\\-access"}) {
    EXPECT_NE(r.out.find(needle), std::string::npos) << needle;
  }
  // man itself can render it, when installed.
  const auto rendered = tool.run_script(
      "command -v man >/dev/null || { echo no-man; exit 0; }; \"$ECAT\" man | man -l - | head -3");
  EXPECT_EQ(rendered.status, 0) << rendered.err;
}

TEST(DocsTool, BashCompletionCompletesCommandsAndOptions) {
  ToolRunner tool("completion");
  const auto r = tool.run_script(
      "command -v bash >/dev/null || { echo skipped; exit 0; }; cd '" + tool.dir().string() +
      "' && \"$ECAT\" completion bash > comp.sh && bash -c 'source ./comp.sh; "
      "COMP_WORDS=(ecat upl); COMP_CWORD=1; _ecat; echo \"${COMPREPLY[*]}\"; "
      "COMP_WORDS=(ecat reg_read --na); COMP_CWORD=2; _ecat; echo \"${COMPREPLY[*]}\"'");
  ASSERT_EQ(r.status, 0) << r.err;
  if (r.out == "skipped\n") GTEST_SKIP() << "bash is not installed";
  EXPECT_EQ(r.out, "upload\n--name\n");
  const auto bad = tool.run("completion fish");
  EXPECT_EQ(bad.status, 2);
}

}  // namespace
}  // namespace ecat::test
