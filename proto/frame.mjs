// frame.mjs - the stream's frame decoder lives in the JavaScript client's package,
// clients/js/src/frame.mjs (one copy); this re-exports it for the scripts and tests that import it
// from proto/.
export * from '../clients/js/src/frame.mjs';
