#include "command_line.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "tileset_format.h"

namespace surfcast::cli {

std::string versionText(const std::string& program) {
    return program + " " SURFCAST_VERSION "\ntile sets: reads format versions " + std::to_string(kOldestFormatVersion) + " to " +
           std::to_string(kPartsFormatVersion) + ", writes " + std::to_string(kFormatVersion) + " (" +
           std::to_string(kPartsFormatVersion) + " where a set's blocks lie in several files: docs/FORMAT.md)";
}

std::string HelpFormatter::make_help(const CLI::App* app, std::string name, CLI::AppFormatMode mode) const {
    if (mode == CLI::AppFormatMode::Sub) return make_expanded(app);
    std::string out;
    if (auto it = usage_.find(app); it != usage_.end()) {
        out = "usage: " + it->second + "\n";
    } else {
        out = make_usage(app, name);
    }
    if (const std::string d = make_description(app); !d.empty()) out += "\n" + d;
    out += make_positionals(app);
    out += make_groups(app, mode);
    out += make_subcommands(app, mode);
    if (const std::string f = make_footer(app); !f.empty()) out += "\n" + f;
    // One blank line between groups (CLI11 puts two).
    for (size_t at; (at = out.find("\n\n\n")) != std::string::npos;) out.erase(at, 1);
    return out;
}

std::string HelpFormatter::make_option_desc(const CLI::Option* opt) const {
    const size_t width = 80 - get_column_width();
    std::string out, line;
    std::istringstream words(CLI::Formatter::make_option_desc(opt));
    for (std::string word; words >> word;) {
        if (!line.empty() && line.size() + 1 + word.size() > width) {
            out += line + "\n";
            line.clear();
        }
        line += (line.empty() ? "" : " ") + word;
    }
    return out + line;
}

std::shared_ptr<HelpFormatter> configure(CLI::App& app) {
    auto formatter = std::make_shared<HelpFormatter>();
    formatter->label("Usage", "usage");
    formatter->column_width(28);
    app.formatter(formatter);
    app.set_help_flag("-h,--help", "this text");
    app.set_version_flag("--version", versionText(app.get_name()), "the program's version and the tile-set formats it reads and writes");
    app.allow_extras();
    // An option given twice takes its last value; a flag takes no value (--quiet=false is an error).
    app.option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast)->disable_flag_override();
    return formatter;
}

int usageError(const std::string& program, const std::string& message) {
    std::fprintf(stderr, "%s: %s\n(see %s --help)\n", program.c_str(), message.c_str(), program.c_str());
    return 2;
}

CLI::App* subcommand(CLI::App& app, const std::string& name) {
    for (CLI::App* sub : app.get_subcommands({}))
        if (sub->get_name() == name) return sub;
    return nullptr;
}

int parse(CLI::App& app, std::vector<std::string> args, std::vector<std::string>* positionals, const ExtraArgument& extra) {
    const std::string program = app.get_name();
    auto asked = [&](std::initializer_list<const char*> names) {
        for (const std::string& a : args)
            for (const char* n : names)
                if (a == n) return true;
        return false;
    };
    // CLI11's "--" (the rest as positionals) and "++" (the end of a
    // subcommand) are no options of these programs.
    for (const char* mark : {"--", "++"})
        if (asked({mark})) return usageError(program, std::string("unknown option ") + mark);
    try {
        std::reverse(args.begin(), args.end());  // CLI11 takes the arguments last first
        app.parse(args);
    } catch (const CLI::CallForHelp&) {
        std::fputs(app.help().c_str(), stdout);  // the help of the subcommand given, where one was
        return 0;
    } catch (const CLI::CallForVersion& e) {
        std::printf("%s\n", e.what());
        return 0;
    } catch (const std::exception& e) {
        // A value checked as it was read failed before the parser reached
        // --help or --version: they still come first.
        if (asked({"-h", "--help"})) {
            std::fputs(app.help().c_str(), stdout);
            return 0;
        }
        if (asked({"--version"})) {
            std::printf("%s\n", versionText(program).c_str());
            return 0;
        }
        if (dynamic_cast<const CLI::ParseError*>(&e) || dynamic_cast<const UsageError*>(&e)) return usageError(program, e.what());
        throw;
    }
    // What no option took, in the subcommand that was parsing it: an unknown
    // option is an error; the rest are positionals where the caller takes them.
    const CLI::App* where = &app;
    for (const CLI::App* sub : app.get_subcommands())
        if (sub->parsed()) where = sub;
    std::vector<std::string> left = where->remaining();
    const std::vector<std::string> above = app.remaining();
    if (where != &app) left.insert(left.begin(), above.begin(), above.end());
    auto unknown = [&](const std::string& arg) {
        if (extra) return usageError(program, extra(*where, arg));
        return usageError(program, (arg.size() > 1 && arg[0] == '-' ? "unknown option " : "unexpected argument ") + arg);
    };
    for (const std::string& arg : left)
        if (arg.size() > 1 && arg[0] == '-') return unknown(arg);
    for (const std::string& arg : left) {
        if (!positionals) return unknown(arg);
        positionals->push_back(arg);
    }
    return -1;
}

CLI::Option* option(CLI::App& app, const std::string& spec, const std::string& type, const std::string& help,
                    std::function<void(const std::string&)> set) {
    return app.add_option_function<std::string>(spec, std::move(set), help)->type_name(type)->trigger_on_parse();
}

CLI::Option* flag(CLI::App& app, const std::string& spec, const std::string& help, std::function<void()> set) {
    return app.add_flag_callback(spec, std::move(set), help)->trigger_on_parse();
}

void addHttpOptions(CLI::App& app, HttpOptions& http, const std::string& group, std::function<void()> given) {
    auto note = [given] {
        if (given) given();
    };
    option(app, "--header", "'NAME: VALUE'", "a header sent with every request (repeatable)", [&http, note](const std::string& v) {
        if (v.find(':') == std::string::npos || v.find(':') == 0) throw UsageError("--header wants 'Name: value'");
        http.headers.push_back(v);
        note();
    })->group(group);
    option(app, "--token-file", "F", "a file holding a bearer token (\"Authorization: Bearer TOKEN\")", [&http, note](const std::string& v) {
        http.tokenFile = v;
        note();
    })->group(group);
    option(app, "--ca-file", "F", "PEM certificates to verify hosts with, instead of the system's", [&http, note](const std::string& v) {
        http.caFile = v;
        note();
    })->group(group);
    flag(app, "--insecure", "no certificate verification (tests only)", [&http, note] {
        http.insecure = true;
        note();
    })->group(group);
    flag(app, "--redirect-credentials", "send the headers and token to the origins redirects lead to, too", [&http, note] {
        http.redirectCredentials = true;
        note();
    })->group(group);
}

bool parseNumber(const std::string& text, double* out) {
    char* end = nullptr;
    *out = std::strtod(text.c_str(), &end);
    return end != text.c_str() && *end == '\0';
}

}  // namespace surfcast::cli
