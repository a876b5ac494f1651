// Status and Result<T>: the error channel for anything that comes from disk,
// network or a user (DESIGN.md, Style). Programmer mistakes are asserts instead.
#pragma once

#include <cassert>
#include <optional>
#include <string>
#include <utility>

namespace surfcast {

class [[nodiscard]] Status {
public:
    Status() = default;  // success
    static Status error(std::string message) { return Status(std::move(message), false); }
    // A fault that asking again may clear (a network error, a timeout, HTTP
    // 408, 429 or 5xx); every other error is permanent: the same request gets
    // the same answer, so callers that retry retry only these.
    static Status transient(std::string message) { return Status(std::move(message), true); }

    bool ok() const { return !message_.has_value(); }
    explicit operator bool() const { return ok(); }
    bool isTransient() const { return transient_; }
    // Human-readable reason; names the file and place where one is known.
    const std::string& message() const {
        assert(!ok());
        return *message_;
    }

private:
    Status(std::string message, bool transient) : message_(std::move(message)), transient_(transient) {}
    std::optional<std::string> message_;
    bool transient_ = false;
};

template <typename T>
class [[nodiscard]] Result {
public:
    Result(T value) : value_(std::move(value)) {}
    Result(Status status) : status_(std::move(status)) { assert(!status_.ok()); }

    bool ok() const { return value_.has_value(); }
    explicit operator bool() const { return ok(); }
    const Status& status() const { return status_; }
    T& value() {
        assert(ok());
        return *value_;
    }
    const T& value() const {
        assert(ok());
        return *value_;
    }
    T* operator->() { return &value(); }
    const T* operator->() const { return &value(); }
    T& operator*() { return value(); }

private:
    std::optional<T> value_;
    Status status_;
};

}  // namespace surfcast

// Propagate a failed Status from an expression returning Status.
#define SC_TRY(expr)                      \
    do {                                  \
        ::surfcast::Status sc_st_ = (expr); \
        if (!sc_st_.ok()) return sc_st_;  \
    } while (0)
