//! The one error type at the HTTP boundary: precise 4xx messages, a generic 5xx body with the
//! details in the log (STYLE: one mapping per boundary).

use axum::Json;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;

/// An error answered to an HTTP client as `{"error": {"kind": ..., "message": ...}}`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AppError {
    /// The body is not well-formed JSON (syntax error, NaN/Infinity literal, number overflow).
    #[error("{0}")]
    MalformedJson(String),
    /// The request is well-formed but a value is unknown, missing or out of range.
    #[error("{0}")]
    Invalid(String),
    /// An uploaded asset or mesh could not be read.
    #[error("{0}")]
    BadUpload(String),
    /// No asset, job or route of that name.
    #[error("{0}")]
    NotFound(String),
    /// The name is taken.
    #[error("{0}")]
    Conflict(String),
    /// Missing or wrong bearer token.
    #[error("a valid `Authorization: Bearer <token>` header is required")]
    Unauthorized,
    /// The body is larger than the configured limit.
    #[error("request body is larger than the limit of {limit} bytes")]
    TooLarge {
        /// The limit in bytes.
        limit: u64,
    },
    /// An asset exceeds a limit of the service (its decoded size or the memory budget); the
    /// message names the limit.
    #[error("{0}")]
    OverLimit(String),
    /// Capacity is exhausted (session limit, render queue full) or the service is not ready.
    #[error("{0}")]
    Unavailable(String),
    /// An extractor rejected the request with its own status (e.g. a wrong content type).
    #[error("{message}")]
    Rejected {
        /// The status the extractor chose.
        status: StatusCode,
        /// Its message.
        message: String,
    },
    /// Anything else: logged, answered as a generic 500.
    #[error(transparent)]
    Internal(#[from] anyhow::Error),
}

#[derive(Serialize, utoipa::ToSchema)]
pub(crate) struct ErrorBody {
    /// The error.
    pub error: ErrorDetail,
}

#[derive(Serialize, utoipa::ToSchema)]
pub(crate) struct ErrorDetail {
    /// Machine-readable kind: `malformed_json`, `invalid`, `bad_upload`, `not_found`,
    /// `conflict`, `unauthorized`, `too_large`, `unavailable`, `rejected`, `internal`.
    pub kind: &'static str,
    /// Human-readable explanation.
    pub message: String,
}

impl AppError {
    /// HTTP status of the error.
    pub fn status(&self) -> StatusCode {
        match self {
            AppError::MalformedJson(_) => StatusCode::BAD_REQUEST,
            AppError::Invalid(_) | AppError::BadUpload(_) => StatusCode::UNPROCESSABLE_ENTITY,
            AppError::NotFound(_) => StatusCode::NOT_FOUND,
            AppError::Conflict(_) => StatusCode::CONFLICT,
            AppError::Unauthorized => StatusCode::UNAUTHORIZED,
            AppError::TooLarge { .. } | AppError::OverLimit(_) => StatusCode::PAYLOAD_TOO_LARGE,
            AppError::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
            AppError::Rejected { status, .. } => *status,
            AppError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    /// Short machine-readable kind, also the `kind` label of the errors metric.
    pub fn kind(&self) -> &'static str {
        match self {
            AppError::MalformedJson(_) => "malformed_json",
            AppError::Invalid(_) => "invalid",
            AppError::BadUpload(_) => "bad_upload",
            AppError::NotFound(_) => "not_found",
            AppError::Conflict(_) => "conflict",
            AppError::Unauthorized => "unauthorized",
            AppError::TooLarge { .. } | AppError::OverLimit(_) => "too_large",
            AppError::Unavailable(_) => "unavailable",
            AppError::Rejected { .. } => "rejected",
            AppError::Internal(_) => "internal",
        }
    }

    /// Maps a serde_json error: syntax errors (incl. NaN literals and overflowing numbers) are
    /// 400, well-formed JSON with wrong fields or types is 422.
    pub fn from_json(err: &serde_json::Error) -> Self {
        use serde_json::error::Category;
        match err.classify() {
            Category::Syntax | Category::Eof | Category::Io => {
                AppError::MalformedJson(format!("malformed JSON: {err}"))
            }
            Category::Data => AppError::Invalid(format!("invalid request: {err}")),
        }
    }

    /// Maps an axum extractor rejection, keeping its status; a length-limit rejection becomes
    /// [`AppError::TooLarge`].
    pub fn from_rejection(status: StatusCode, message: String, limit: u64) -> Self {
        if status == StatusCode::PAYLOAD_TOO_LARGE {
            AppError::TooLarge { limit }
        } else {
            AppError::Rejected { status, message }
        }
    }
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        let status = self.status();
        let message = if let AppError::Internal(err) = &self {
            tracing::error!(error = format!("{err:#}"), "internal error");
            "internal server error (details are in the server log)".to_owned()
        } else {
            self.to_string()
        };
        let body = ErrorBody {
            error: ErrorDetail {
                kind: self.kind(),
                message,
            },
        };
        let mut response = (status, Json(body)).into_response();
        if matches!(self, AppError::Unavailable(_)) {
            // Every 503 is transient (a full queue, a taken memory budget, loading, a stalled
            // render path): clients are told when to try again.
            response
                .headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from_static("1"));
        }
        if matches!(self, AppError::Unauthorized) {
            response
                .headers_mut()
                .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
        }
        response.extensions_mut().insert(ErrorKind(self.kind()));
        response
    }
}

/// Marker left on error responses so the metrics middleware can count errors by kind.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ErrorKind(pub &'static str);
