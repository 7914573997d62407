// recording.mjs - the recording reader and builder live in the JavaScript client's package,
// clients/js/src/recording.mjs (one copy); this re-exports it for the scripts and tests that
// import it from proto/.
export * from '../clients/js/src/recording.mjs';
