// errors.js - what the clothd client throws. Every answer that is not a success becomes one of
// these: an HTTP status of 400 or more (its problem+json body, RFC 9457, read into the error),
// no answer in time, no connection, or an answer that is not what the protocol says.
//
//   ClothdError
//   ├─ ClientError (4xx): BadRequest 400, Unauthorized 401, Forbidden 403, NotFound 404,
//   │    MethodNotAllowed 405, Conflict 409, PayloadTooLarge 413, UriTooLong 414,
//   │    Unprocessable 422, RateLimited 429
//   ├─ ServerError (5xx): Unavailable 503, Busy 503 `busy`
//   ├─ TimeoutError, ConnectionError (no answer)
//   └─ ProtocolError (an answer or a stream message that breaks the protocol)

const PROBLEM_PREFIX = 'urn:clothd:problem:';

export class ClothdError extends Error {
  /**
   * @param {string} message
   * @param {{status?: number|null, problem?: object|null, body?: any, requestId?: string|null,
   *   retryAfter?: number|null, method?: string, path?: string, allow?: string[]|null, cause?: any}} [info]
   */
  constructor(message, info = {}) {
    super(message, info.cause === undefined ? undefined : { cause: info.cause });
    this.name = new.target.name;
    /** The HTTP status, or null when there was no answer. */
    this.status = info.status ?? null;
    /** The problem+json body as the server sent it, or null. */
    this.problem = info.problem ?? null;
    /** The answer's body when it is not a problem (a 503 health answer, an HTML page), or null. */
    this.body = info.body ?? null;
    const p = this.problem ?? {};
    /** The problem's type URI, e.g. urn:clothd:problem:out-of-range. */
    this.type = typeof p.type === 'string' ? p.type : null;
    /** The type's last part, e.g. out-of-range (PROTOCOL.md's "type slug"). */
    this.slug = this.type?.startsWith(PROBLEM_PREFIX) ? this.type.slice(PROBLEM_PREFIX.length) : null;
    this.title = typeof p.title === 'string' ? p.title : null;
    this.detail = typeof p.detail === 'string' ? p.detail : null;
    /** The parameter or field to blame, where the server names one. */
    this.param = typeof p.param === 'string' ? p.param : null;
    /** The X-Request-Id the request carried. */
    this.requestId = info.requestId ?? null;
    /** Seconds to wait before asking again (Retry-After), for 429 and 503. */
    this.retryAfter = info.retryAfter ?? null;
    /** The methods the path has (Allow), for 405. */
    this.allow = info.allow ?? null;
    this.method = info.method ?? null;
    this.path = info.path ?? null;
  }
}

export class ClientError extends ClothdError {}
export class BadRequest extends ClientError {}
export class Unauthorized extends ClientError {}
export class Forbidden extends ClientError {}
export class NotFound extends ClientError {}
export class MethodNotAllowed extends ClientError {}
export class Conflict extends ClientError {}
export class PayloadTooLarge extends ClientError {}
export class UriTooLong extends ClientError {}
export class Unprocessable extends ClientError {}
export class RateLimited extends ClientError {}
export class ServerError extends ClothdError {}
export class Unavailable extends ServerError {}
export class Busy extends ServerError {}
export class TimeoutError extends ClothdError {}
export class ConnectionError extends ClothdError {}
export class ProtocolError extends ClothdError {}

/** The class of each status; a status not here falls back to its family. */
export const STATUS_ERRORS = {
  400: BadRequest, 401: Unauthorized, 403: Forbidden, 404: NotFound, 405: MethodNotAllowed,
  409: Conflict, 413: PayloadTooLarge, 414: UriTooLong, 422: Unprocessable, 429: RateLimited,
  503: Unavailable,
};

/** The error class for an HTTP status and problem type slug (503 `busy` is Busy). */
export function errorClass(status, slug) {
  if (status === 503 && slug === 'busy') return Busy;
  return STATUS_ERRORS[status] ?? (status >= 500 ? ServerError : ClientError);
}

/**
 * The error of a refused answer.
 * @param {number} status @param {string} contentType @param {string} text the answer's body
 * @param {{method: string, path: string, requestId: string|null, retryAfter: string|null, allow: string|null}} request
 */
export function errorFromAnswer(status, contentType, text, request) {
  let parsed = null;
  try { parsed = JSON.parse(text); } catch { /* an HTML page of libmicrohttpd's, or nothing */ }
  const isProblem = /problem\+json/.test(contentType) && parsed && typeof parsed === 'object';
  const problem = isProblem ? parsed : null;
  const body = isProblem ? null : (parsed ?? (text || null));
  const slug = problem?.type?.startsWith?.(PROBLEM_PREFIX) ? problem.type.slice(PROBLEM_PREFIX.length) : null;
  const Class = errorClass(status, slug);
  // The message is the server's own words (what a page shows the user); status, slug and the
  // request are in the fields.
  const why = problem?.detail || problem?.title || (typeof body === 'string' && body.trim() ? body.slice(0, 200)
    : `${request.method} ${request.path}: HTTP ${status}`);
  const retry = request.retryAfter != null && /^\d+$/.test(request.retryAfter.trim()) ? Number(request.retryAfter) : null;
  return new Class(why, {
    status, problem, body, requestId: request.requestId, retryAfter: retry,
    allow: request.allow ? request.allow.split(',').map((m) => m.trim()).filter(Boolean) : null,
    method: request.method, path: request.path,
  });
}
