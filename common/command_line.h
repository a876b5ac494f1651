// The programs' command lines, parsed by CLI11: one look for --help,
// --version and usage errors across surfcast-build, -serve, -view and -export.
// An option's value is checked as the parser reads it (its callback, in the
// order given); a bad one throws UsageError with the message the user sees.
// Positional arguments are handed back as they are (parse()), never split
// by CLI11's vector syntax ("[a,b]").
#pragma once

#include <CLI/CLI.hpp>
#include <functional>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "tile_source.h"

namespace surfcast::cli {

// A usage error: exit status 2, "PROGRAM: message" and a pointer to --help.
struct UsageError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// "PROGRAM VERSION" and the tile-set format versions it reads and writes.
std::string versionText(const std::string& program);

// --help's layout: the usage lines first ("usage: ..."; the app's own where
// given, else generated), then the description, the options by group and
// the footer.
class HelpFormatter : public CLI::Formatter {
public:
    std::string make_help(const CLI::App* app, std::string name, CLI::AppFormatMode mode) const override;
    // Descriptions wrapped to 80 columns beside the options' names.
    std::string make_option_desc(const CLI::Option* opt) const override;
    // The usage lines of `app` (each a line of "PROGRAM ..."), in place of the generated one.
    void usage(const CLI::App* app, std::string lines) { usage_[app] = std::move(lines); }

private:
    std::map<const CLI::App*, std::string> usage_;
};

// Sets up `app` (made as CLI::App(description, program)): -h/--help,
// --version, the help layout, arguments no option takes kept for parse(),
// an option given twice taking its last value, flags taking no value. Call
// before adding options and subcommands, which inherit it. Returns the
// formatter.
std::shared_ptr<HelpFormatter> configure(CLI::App& app);

// What parse() says of an argument no option of `where` took (`where`: the
// app or the subcommand that was parsing): the message of its usage error.
// The default: "unknown option X", or "unexpected argument X".
using ExtraArgument = std::function<std::string(const CLI::App& where, const std::string& argument)>;

// Parses `args` (the program's arguments, without its name). Returns -1 to
// go on, or the exit status: 0 after --help or --version (printed on
// stdout; they win over a bad value given with them), 2 after a usage error
// (on stderr). The arguments no option took that do not start with '-' go
// to `positionals` in order (null: each is an error, as every unknown
// option is); CLI11's "--" and "++" are unknown options.
int parse(CLI::App& app, std::vector<std::string> args, std::vector<std::string>* positionals = nullptr,
          const ExtraArgument& extra = {});

// The subcommand of `app` named `name`, or null.
CLI::App* subcommand(CLI::App& app, const std::string& name);

// "PROGRAM: message" and "(see PROGRAM --help)" on stderr; returns 2.
int usageError(const std::string& program, const std::string& message);

// An option taking a value that `set` reads as the parser meets it (so a
// later one wins, as given); `set` throws UsageError where it is bad. `type`
// names the value in --help.
CLI::Option* option(CLI::App& app, const std::string& spec, const std::string& type, const std::string& help,
                    std::function<void(const std::string&)> set);
// A flag that `set` notes as the parser meets it.
CLI::Option* flag(CLI::App& app, const std::string& spec, const std::string& help, std::function<void()> set);

// How to reach a set or an input at a URL (HttpOptions): --header 'N: V'
// (repeatable), --token-file F, --ca-file F, --insecure and
// --redirect-credentials, in help group `group`; `given` is called for each.
void addHttpOptions(CLI::App& app, HttpOptions& http, const std::string& group, std::function<void()> given = {});

// A number: the whole of `text` read by strtod; false where it is not one.
bool parseNumber(const std::string& text, double* out);

}  // namespace surfcast::cli
