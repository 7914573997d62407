// api.js - the HTTP API of PROTOCOL.md from the page: JSON in and out, problem+json errors as
// ApiError, the bearer token when one is needed (asked for on the first 401, kept for the tab).

const TOKEN_KEY = 'clothd.token';

export class ApiError extends Error {
  /** @param {number} status @param {object} problem the problem+json body (type, title, detail, param) */
  constructor(status, problem) {
    super(problem.detail || problem.title || `HTTP ${status}`);
    this.status = status;
    this.problem = problem;
    this.param = problem.param ?? null;
  }
}

export class Api {
  /** @param {{base?: string, askToken?: (reason: string) => Promise<string|null>}} [options] */
  constructor(options = {}) {
    this.base = options.base ?? '';
    this.askToken = options.askToken ?? null;
    this.token = sessionStorage.getItem(TOKEN_KEY);
    this.requestSeq = 0;
    this.clientId = Math.random().toString(36).slice(2, 8);
  }

  /** The X-Request-Id of the next request: events carrying it are this page's own. */
  nextRequestId() {
    return `viewer-${this.clientId}-${++this.requestSeq}`;
  }

  isOwnRequest(id) {
    return typeof id === 'string' && id.startsWith(`viewer-${this.clientId}-`);
  }

  /**
   * @param {string} method @param {string} path under the origin, e.g. /v1/sim
   * @param {object|ArrayBuffer|Blob} [body] JSON-encoded unless binary
   * @param {{accept?: string, raw?: boolean}} [options] raw: answer the Response itself
   */
  async request(method, path, body, options = {}) {
    for (let attempt = 0; ; attempt++) {
      const headers = { 'X-Request-Id': this.nextRequestId() };
      if (this.token) headers.Authorization = `Bearer ${this.token}`;
      if (options.accept) headers.Accept = options.accept;
      let payload;
      if (body instanceof ArrayBuffer || body instanceof Blob) payload = body;
      else if (body !== undefined) {
        payload = JSON.stringify(body);
        headers['Content-Type'] = 'application/json';
      }
      const res = await fetch(this.base + path, { method, headers, body: payload, cache: 'no-store' });
      if ((res.status === 401 || res.status === 403) && this.askToken && attempt < 3) {
        const problem = await res.json().catch(() => ({}));
        const token = await this.askToken(problem.detail || 'This clothd needs a token.');
        if (token) {
          this.token = token;
          sessionStorage.setItem(TOKEN_KEY, token);
          continue;
        }
      }
      if (!res.ok) {
        const text = await res.text();
        let problem;
        try { problem = JSON.parse(text); } catch { problem = { title: res.statusText, detail: text.slice(0, 200) }; }
        throw new ApiError(res.status, problem);
      }
      if (options.raw) return res;
      return res.status === 204 ? null : res.json();
    }
  }

  get(path) { return this.request('GET', path); }
  post(path, body) { return this.request('POST', path, body ?? {}); }
  patch(path, body) { return this.request('PATCH', path, body); }
  put(path, body) { return this.request('PUT', path, body); }
  delete(path) { return this.request('DELETE', path); }
}
