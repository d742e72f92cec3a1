package vlaprobe.diarc;

import java.net.URI;
import java.net.http.HttpClient;
import java.net.http.WebSocket;
import java.time.Duration;
import java.util.ArrayList;
import java.util.LinkedHashSet;
import java.util.List;
import java.util.Map;
import java.util.Set;
import java.util.TreeSet;
import java.util.concurrent.CompletableFuture;
import java.util.concurrent.CompletionStage;
import java.util.concurrent.CountDownLatch;
import java.util.concurrent.TimeUnit;

/**
 * Follows the episodes of a {@code vlaprobe serve} server and keeps the belief set from the per-step diffs,
 * handing each step's diff to a {@link BeliefSink}. JDK only ({@code java.net.http.WebSocket}).
 *
 * <pre>
 *   java -cp out vlaprobe.diarc.LiveClient ws://127.0.0.1:6006/ws [--token T] [--start TASK [--init N] [--driver D]] [--once]
 * </pre>
 */
public final class LiveClient implements WebSocket.Listener {
    private final BeliefSink sink;
    private final Set<String> beliefs = new TreeSet<>();
    private final StringBuilder partial = new StringBuilder();
    private final CountDownLatch ended = new CountDownLatch(1);
    private String startCommand;
    private boolean started;
    private volatile boolean gotEnd;

    public LiveClient(BeliefSink sink) {
        this.sink = sink;
    }

    /** The current belief set (DIARC terms). */
    public synchronized Set<String> beliefs() {
        return new TreeSet<>(beliefs);
    }

    /** Connect; if {@code startCommand} is not null it is sent after the server's hello. */
    public WebSocket connect(String url, String token, String startCommand) {
        this.startCommand = startCommand;
        String full = token == null ? url : url + (url.contains("?") ? "&" : "?") + "token=" + token;
        return HttpClient.newHttpClient().newWebSocketBuilder()
                .connectTimeout(Duration.ofSeconds(10))
                .buildAsync(URI.create(full), this)
                .join();
    }

    /** Wait for the end of the episode being followed; false on timeout or if the connection closed first. */
    public boolean awaitEnd(long seconds) throws InterruptedException {
        return ended.await(seconds, TimeUnit.SECONDS) && gotEnd;
    }

    @Override
    public CompletionStage<?> onText(WebSocket ws, CharSequence data, boolean last) {
        partial.append(data);
        if (last) {
            String text = partial.toString();
            partial.setLength(0);
            handle(ws, Json.object(Json.parse(text)));
        }
        ws.request(1);
        return null;
    }

    @Override
    public void onError(WebSocket ws, Throwable error) {
        System.err.println("vlaprobe client: " + error);
        ended.countDown();
    }

    @Override
    public CompletionStage<?> onClose(WebSocket ws, int status, String reason) {
        ended.countDown();
        return CompletableFuture.completedFuture(null);
    }

    private synchronized void handle(WebSocket ws, Map<String, Object> msg) {
        String type = String.valueOf(msg.get("type"));
        switch (type) {
            case "hello":
                if (startCommand != null && !started) {
                    started = true;
                    ws.sendText(startCommand, true);
                }
                break;
            case "episode_start":
                episodeStart(msg);
                break;
            case "history":
                episodeStart(Json.object(msg.get("start")));
                for (Object step : Json.array(msg.get("steps"))) step(Json.object(step));
                break;
            case "step":
                step(msg);
                break;
            case "episode_end":
                int steps = ((Double) msg.get("steps")).intValue();
                sink.episodeEnd(String.valueOf(msg.get("episode_id")), Boolean.TRUE.equals(msg.get("success")), steps);
                System.out.println("END " + msg.get("episode_id") + " success=" + msg.get("success") + " steps=" + steps);
                System.out.println("BELIEFS " + String.join(" ", beliefs));
                gotEnd = true;
                ended.countDown();
                break;
            case "error":
                System.out.println("ERROR " + msg.get("message"));
                break;
            default:
                break;
        }
    }

    private void episodeStart(Map<String, Object> start) {
        beliefs.clear();
        sink.episodeStart(String.valueOf(start.get("episode_id")), String.valueOf(start.get("instruction")));
        List<String> defined = new ArrayList<>(), undefined = new ArrayList<>();
        Map<String, Object> atoms = Json.object(start.get("atoms")), flags = Json.object(start.get("defined"));
        for (String head : List.of("object", "action")) {
            List<Object> names = Json.array(atoms.get(head)), marks = Json.array(flags.get(head));
            for (int i = 0; i < names.size(); i++) {
                boolean known = i >= marks.size() || !Boolean.FALSE.equals(marks.get(i)); // null: every atom
                (known ? defined : undefined).add(String.valueOf(names.get(i)));
            }
        }
        sink.atoms(defined, undefined);
    }

    private void step(Map<String, Object> step) {
        Map<String, Object> diff = Json.object(step.get("beliefs"));
        Set<String> on = strings(diff.get("asserted"));
        Set<String> off = strings(diff.get("retracted"));
        beliefs.removeAll(off);
        beliefs.addAll(on);
        if (!off.isEmpty()) sink.retractBeliefs(off);
        if (!on.isEmpty()) sink.assertBeliefs(on);
        List<String> active = new ArrayList<>();
        for (Object v : Json.array(step.get("violations"))) {
            Map<String, Object> m = Json.object(v);
            active.add(m.get("rule") + ": " + m.get("message"));
        }
        int t = ((Double) step.get("t")).intValue();
        sink.violations(t, active);
        Map<String, Object> alarm = Json.object(step.get("alarm"));
        if (!alarm.isEmpty()) {
            List<String> rules = new ArrayList<>(strings(alarm.get("rules")));
            List<String> atoms = new ArrayList<>(strings(alarm.get("atoms")));
            sink.alarm(t, String.valueOf(alarm.get("kind")), String.valueOf(alarm.get("reason")), rules, atoms);
        }
        Object handover = step.get("handover");
        if (handover != null) {
            String reason = String.valueOf(Json.object(step.get("takeover")).getOrDefault("reason", ""));
            sink.handover(t, "to_expert".equals(handover), reason);
        }
    }

    private static Set<String> strings(Object v) {
        Set<String> out = new LinkedHashSet<>();
        for (Object x : Json.array(v)) out.add(String.valueOf(x));
        return out;
    }

    /** Prints each step's diff; stands in for a DIARC component. */
    static final class PrintingSink implements BeliefSink {
        @Override
        public void assertBeliefs(Set<String> terms) {
            System.out.println("ASSERT " + String.join(" ", terms));
        }

        @Override
        public void retractBeliefs(Set<String> terms) {
            System.out.println("RETRACT " + String.join(" ", terms));
        }

        @Override
        public void violations(int t, List<String> active) {
            if (!active.isEmpty()) System.out.println("VIOLATIONS t=" + t + " " + active);
        }

        @Override
        public void alarm(int t, String kind, String reason, List<String> rules, List<String> atoms) {
            System.out.println("ALARM t=" + t + " " + kind + ": " + reason + " rules=" + rules + " atoms=" + atoms);
        }

        @Override
        public void atoms(List<String> defined, List<String> undefined) {
            System.out.println("ATOMS defined=" + defined.size() + " undefined=" + undefined.size());
            if (!undefined.isEmpty()) System.out.println("UNDEFINED " + String.join(" ", undefined));
        }

        @Override
        public void handover(int t, boolean toExpert, String reason) {
            System.out.println("HANDOVER t=" + t + (toExpert ? " to_expert (" + reason + ")" : " to_policy"));
        }
    }

    public static void main(String[] args) throws Exception {
        if (args.length < 1) {
            System.err.println("usage: LiveClient ws://HOST:PORT/ws [--token T] [--start TASK [--init N] [--driver D]] [--once]");
            System.exit(2);
        }
        String url = args[0], token = null, task = null, init = "\"random\"", driver = null;
        boolean once = false;
        for (int k = 1; k < args.length; k++) {
            switch (args[k]) {
                case "--token": token = args[++k]; break;
                case "--start": task = args[++k]; break;
                case "--init": init = args[++k]; break;
                case "--driver": driver = args[++k]; break;
                case "--once": once = true; break;
                default: System.err.println("unknown argument " + args[k]); System.exit(2);
            }
        }
        String start = null;
        if (task != null) {
            String t = task.matches("\\d+") ? task : Json.quote(task);
            String d = driver == null ? "" : ",\"driver\":" + Json.quote(driver);
            start = "{\"type\":\"start\",\"task\":" + t + ",\"init\":" + init + d + "}";
        }
        LiveClient client = new LiveClient(new PrintingSink());
        WebSocket ws = client.connect(url, token, start);
        if (once) {
            boolean ok = client.awaitEnd(600);
            ws.sendClose(WebSocket.NORMAL_CLOSURE, "done").get(5, TimeUnit.SECONDS);
            System.exit(ok ? 0 : 1);
        }
        new CountDownLatch(1).await();
    }
}
