/*
 * KinComp web UI: the answer of a request whose work may go on in the background. Every
 * analysis (a trace or summary at /trace and /analyze, a campaign test's trace, a campaign's
 * joint analysis, a printed artifact's readings) answers 200 with its result when it is
 * done within 20 s, else 202 with {job} to poll (GET /jobs/<id>, whose result is then the
 * stored run's id). K.afterJob turns either answer into what the 200 brings: it polls the
 * job as its Retry-After says (once a second), a 429 of a poll (KinComp rations reads while
 * a print runs) waits as that answer says, and then loads the result.
 *
 * No DOM here: ``env`` gives the page's means (default: OctoPrint.get on KinComp's API,
 * window.setTimeout, jQuery's Deferred), so that node's unit tests can run it
 * (tests/js/jobs.test.js).
 */
(function (root) {
    "use strict";
    var K = root.KinComp = root.KinComp || {};
    var _ = root._;

    var pageEnv = function () {
        return {
            get: function (path) {
                return K.get(K.API(path));
            },
            later: function (fn, ms) {
                return root.setTimeout(fn, ms);
            },
            Deferred: root.$.Deferred
        };
    };

    // (body, the request object) of a request's success; OctoPrint.upload resolves with
    // one array [body, status text, XMLHttpRequest], jQuery's requests with the three
    var answer = function (args) {
        var first = args[0];
        if (_.isArray(first) && first.length === 3 && first[2] && first[2].status !== undefined) {
            return {body: first[0], xhr: first[2]};
        }
        return {body: first, xhr: args[2]};
    };

    // the request object of a failure (OctoPrint.upload rejects with [request, ...])
    var failure = function (args) {
        var first = args[0];
        return _.isArray(first) ? first[0] : first;
    };

    // whether a 2xx answer is the 202 of a job still under way
    K.pendingJob = function (body, xhr) {
        if (xhr && xhr.status !== undefined) return xhr.status === 202 && !!(body && body.job);
        return !!(body && body.job && body.job.id && _.keys(body).length === 1);
    };

    // seconds a 202 or 429 asks the client to wait (Retry-After), else ``fallback``
    K.retryAfter = function (xhr, fallback) {
        var header = xhr && xhr.getResponseHeader ? xhr.getResponseHeader("Retry-After") : null;
        var s = parseFloat(header);
        return isFinite(s) && s > 0 ? s : fallback;
    };

    /*
     * A read that a rationed server answers with 429 (KinComp answers a few requests a
     * second while a print runs: a page loading after a reload asks for several things at
     * once) is asked again as its Retry-After says, up to ``tries`` times (default 15, about
     * half a minute); the deferred resolves or rejects with what the last answer brought,
     * as the request itself would. request(): a new request's deferred.
     */
    K.retrying = function (request, env, tries) {
        env = env || pageEnv();
        var out = env.Deferred();
        var attempt = function (left) {
            request()
                .done(function () {
                    out.resolve.apply(out, arguments);
                })
                .fail(function (xhr) {
                    if (xhr && xhr.status === 429 && left > 0) {
                        env.later(function () {
                            attempt(left - 1);
                        }, K.retryAfter(xhr, 2) * 1000);
                    } else {
                        out.reject.apply(out, arguments);
                    }
                });
        };
        attempt(tries === undefined ? 15 : tries);
        return out.promise();
    };

    // GET ``url`` (a KinComp API address; ``opts``: OctoPrint.get's, e.g. {dataType:
    // "text"}), asked again while the server rations it
    K.get = function (url, opts) {
        return K.retrying(function () {
            return root.OctoPrint.get(url, opts);
        });
    };

    /*
     * request: the request's deferred (OctoPrint.postJson, OctoPrint.upload ...);
     * load(result, env): a deferred of what the 200 would have brought, from the finished
     * job's result (the run id); options.progress(job): told of each poll (optional).
     * Returns a deferred resolved with that body, or rejected with the request object of
     * the failure (a failed job: {status: 400, responseJSON: {error}}, as its 400 would be).
     */
    K.afterJob = function (request, load, options, env) {
        env = env || pageEnv();
        options = options || {};
        var out = env.Deferred();
        var poll = function (jobId, wait) {
            env.later(function () {
                env.get("jobs/" + encodeURIComponent(jobId))
                    .done(function (resp) {
                        var job = resp && resp.job;
                        if (!job) return out.reject({status: 500, responseJSON: {error: "?"}});
                        if (options.progress) options.progress(job);
                        if (job.state === "done") {
                            load(job.result, env).done(out.resolve).fail(function () {
                                out.reject(failure(arguments));
                            });
                        } else if (job.state === "failed") {
                            out.reject({status: 400, responseJSON: {error: job.error}});
                        } else {
                            poll(jobId, 1);
                        }
                    })
                    .fail(function (xhr) {
                        if (xhr && xhr.status === 429) poll(jobId, K.retryAfter(xhr, 2));
                        else out.reject(xhr);
                    });
            }, wait * 1000);
        };
        request
            .done(function () {
                var a = answer(arguments);
                if (K.pendingJob(a.body, a.xhr)) {
                    if (options.progress) options.progress(a.body.job);
                    poll(a.body.job.id, K.retryAfter(a.xhr, 1));
                } else {
                    out.resolve(a.body);
                }
            })
            .fail(function () {
                out.reject(failure(arguments));
            });
        return out.promise();
    };

    // loaders of what each route's 200 brings, from the job's result (a run id)
    K.loadRun = function (runId, env) {
        return env.get("runs/" + encodeURIComponent(runId));
    };
    // a campaign test's measurement: {campaign, run}
    K.loadCampaignStep = function (campaignId) {
        return function (runId, env) {
            var out = env.Deferred();
            env.get("campaigns/" + encodeURIComponent(campaignId)).done(function (campaign) {
                K.loadRun(runId, env).done(function (run) {
                    out.resolve({campaign: campaign, run: run});
                }).fail(out.reject);
            }).fail(out.reject);
            return out.promise();
        };
    };
    // a campaign's joint analysis: the campaign, analysed
    K.loadCampaign = function (campaignId) {
        return function (runId, env) {
            return env.get("campaigns/" + encodeURIComponent(campaignId));
        };
    };
})(typeof window !== "undefined" ? window : globalThis);
