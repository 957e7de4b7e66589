"""Write backend/core/common_passwords.txt: the common-password list of the password policy.

No download: the list is composed here from the passwords that head every published breach ranking
(written from general knowledge, not copied from a file), keyboard walks, digit and letter runs, and the
usual decorations of the most common base words (a number, a year, "!"). The policy
(backend/core/passwords.py) also strips digits and symbols around a password and undoes leetspeak before
looking it up, so "P@ssw0rd2024!" matches "password": the list holds base words and the long forms.

    .venv/bin/python scripts/make_common_passwords.py
"""

from __future__ import annotations

from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "backend" / "core" / "common_passwords.txt"

BASE = """
123456 password 12345678 qwerty 123456789 12345 1234 111111 1234567 dragon 123123 baseball abc123 football
monkey letmein 696969 shadow master 666666 qwertyuiop 123321 mustang 1234567890 michael 654321 superman
1qaz2wsx 7777777 121212 000000 qazwsx 123qwe killer trustno1 jordan jennifer zxcvbnm asdfgh hunter buster
soccer harley batman andrew tigger sunshine iloveyou charlie robert thomas hockey ranger daniel starwars
klaster 112233 george computer michelle jessica pepper 1111 zxcvbn 555555 11111111 131313 freedom 777777
pass maggie 159753 aaaaaa ginger princess joshua cheese amanda summer love ashley 6969 nicole chelsea biteme
matthew access yankees 987654321 dallas austin thunder taylor matrix william corvette hello martin heather
secret merlin diamond 1234qwer gfhjkm hammer silver 222222 88888888 anthony justin test bailey q1w2e3r4t5
patrick internet scooter orange 11111 golfer cookie richard samantha bigdog guitar jackson whatever mickey
chicken sparky snoopy maverick phoenix camaro peanut morgan welcome falcon cowboy ferrari samsung andrea
smokey steelers joseph mercedes dakota arsenal eagles melissa boomer booboo spider nascar monster tigers
yellow xxxxxx 123123123 gateway marina diablo bulldog qwer1234 compaq purple hardcore banana junior hannah
123654 porsche lakers iceman money cowboys 987654 london tennis 999999 ncc1701 coffee scooby 0000 miller
boston q1w2e3r4 brandon yamaha chester mother forever johnny edward 333333 oliver redsox player nikita knight
fender barney midnight please brandy chicago badboy slayer rangers charles angel flower bigdaddy rabbit
wizard jasper enter rachel chris steven winner adidas victoria natasha 1q2w3e4r jasmine winter prince marine
ghbdtn fishing cocacola casper james 232323 raiders 888888 marlboro gandalf asdfasdf crystal 87654321
12344321 golden panther lauren angela spanky thx1138 angels madison winston shannon mike toyota jordan23
canada sophie apples tiger razz 123abc pokemon qazxsw 55555 qwaszx muffin johnson murphy cooper jonathan
liverpoo david danielle 159357 jackie 1990 123456a 789456 turtle abcd1234 scorpion qazwsxedc 101010 butter
carlos password1 dennis slipknot qwerty123 booger asdf 1991 black startrek 12341234 cameron newyork rainbow
nathan john 1992 rocket viking redskins asdfghjkl 1212 sierra peaches gemini doctor wilson sandra helpme
qwertyui victor florida dolphin pookie captain tucker blue liverpool theman bandit dolphins maddog packers
jaguar lovers nicholas united tiffany maxwell zzzzzz nirvana jeremy monica elephant giants hotdog rosebud
success debbie mountain 444444 xxxxxxxx warrior 1q2w3e4r5t q1w2e3 123456q albert metallic lucky azerty 7777
alex bond007 alexis 1111111 samson 5150 willie scorpio bonnie gators benjamin voodoo driver dexter 2112 jason
calvin freddy 212121 creative 12345a sydney rush2112 1989 asdfghjk red123 bubba 4815162342 passw0rd trouble
gunner happy gordon legend jessie stella qwert eminem arthur apple nissan bear america 1qazxsw2 nothing
parker 4444 rebecca qweqwe garfield 01012011 beavis 69696969 jack asdasd december 2222 102030 252525 11223344
magic apollo skippy 315475 girls kitten golf copper braves shelby godzilla beaver fred tomcat august buddy
airborne 1993 1988 lifehack qqqqqq brooklyn animal platinum phantom online xavier darkness blink182 power
fish green 789456123 voyager police travis 12qwaszx heaven snowball lover abcdef 00000 pakistan 007007
walter playboy blazer cricket sniper hooters donkey willow loveme saturn therock redwings bigboy pumpkin
trinity williams nintendo digital destiny topgun runner marvin guinness chance bubbles testing fire november
minecraft asdf1234 lasvegas sergey broncos cartman private celtic birdie little cassie babygirl donald
beatles 1313 family 12121212 school louise gabriel eclipse fluffy 147258369 lol123 explorer beer nelson
flyers spencer scott lovely gibson doggie cherry andrey snickers buffalo pantera metallica member carter
qwertyu peter alexander steve bronco paradise goober 5555 samuel montana mexico dreams michigan carolina
yankee friends magnum surfer poopoo maximus genius cool vampire lacrosse asd123 aaaa christin kimberly
speedy sharon carmen 111222 kristina sammy racing ou812 sabrina horses 0987654321 qwerty1 pimpin baby
stalker enigma 147147 star poohbear 147258 simple 12345q marcus brian 1987 qweasdzxc drowssap hahaha
caroline barbara dave viper drummer action einstein genesis hello1 scotty friend forest 010203 hotrod google
vanessa spitfire badger maryjane friday alaska 1232323q tester jester jake champion floyd alice jordan1
admin administrator root toor changeme default guest welcome1 login letmein1 passpass password123
iloveyou1 princess1 monkey1 dragon1 sunshine1 shadow1 master1 football1 baseball1 superman1 michael1
qwerty12 abc12345 1q2w3e 1qaz2wsx3edc zaq12wsx zaq1zaq1 !qaz2wsx qazwsx123 qwe123 asdf123 zxc123 zxcvbnm1
trustno1 whatever1 freedom1 computer1 welcome123 letmein123 admin123 root123 test123 test1234 pass123
pass1234 password12 password1234 passw0rd1 p4ssw0rd secret1 secret123 changeme1 default1 guest123 user
user123 username login123 abc abcd abcde abcdefg abcdefgh abcdefghi abcdefghij qwertz qwertzuiop asdfg
asdfghj yxcvbnm 123qweasd 123qweasdzxc qweasd qweasdzxc1 1qazzaq1 q1w2e3r4t5y6 1q2w3e4r5t6y
september october january february march april june july may spring autumn fall sunday monday tuesday
wednesday thursday saturday weekend holiday christmas easter halloween valentine birthday
red orange yellow green blue purple black white silver golden pink brown grey gray
cat dog puppy kitty horse bunny tiger lion eagle shark wolf bear fox panda monkey donkey turtle dolphin
mustang ferrari porsche bmw audi honda toyota nissan ford chevy jeep harley yamaha suzuki kawasaki
chelsea arsenal liverpool manchester barcelona realmadrid juventus milan bayern lakers yankees cowboys
steelers packers patriots eagles giants raiders broncos bulls celtics
jesus jesus1 christ god godisgood blessed faith angel angel1 heaven hallelujah
love loveyou iloveu iloveyou2 lovely lover loving sweetheart sweetie honey darling babe baby1 kisses
hello hello123 hi hey welcome goodbye thanks thankyou please sorry
money cash dollar rich million success winner champion victory power
matrix neo trinity morpheus starwars jedi yoda vader skywalker startrek spock kirk enterprise
pokemon pikachu mario zelda sonic minecraft fortnite roblox naruto goku dragonball batman superman spiderman
ironman hulk thor avengers marvel harrypotter hogwarts gandalf frodo hobbit
soccer football baseball basketball hockey tennis golf cricket rugby volleyball
summer winter spring sunshine rainbow moonlight starlight sunset ocean beach island paradise
computer internet laptop windows linux apple samsung google facebook twitter instagram youtube
letmein openup opensesame access accessgranted secret hidden private mypassword yourpassword
nopassword nopass noaccess unknown nothing something anything everything whatever
qwerty qwertyuiop asdfghjkl zxcvbnm qazwsxedc rfvtgbyhn ujmikolp 1qaz2wsx3edc4rfv qwerasdf qwerasdfzxcv
michael jennifer jessica ashley amanda sarah stephanie melissa nicole elizabeth heather tiffany michelle
christopher matthew joshua david james daniel robert john joseph andrew ryan brandon jason justin william
jonathan anthony kevin thomas charles steven timothy richard jeremy mark eric stephen brian paul adam
alexander benjamin nicholas samuel patrick tyler aaron jose nathan zachary kyle jacob ethan noah liam
emma olivia ava sophia isabella mia charlotte amelia harper evelyn abigail emily ella madison chloe
maria anna laura julia lisa linda susan karen nancy betty helen sandra donna carol ruth sharon
peter george edward henry jack harry oliver charlie thomas william james lucas leo max felix
schalke dortmund hallo passwort geheim schatz sommer fussball ficken hallo123 passwort1
motdepasse soleil bonjour doudou chouchou marseille azertyuiop azerty123 loulou nicolas
contrasena contraseña hola amor teamo tequiero mariposa princesa futbol barcelona
senha amor123 flamengo corinthians palmeiras brasil
parola sifre sifre123 haslo zaq12wsx kochanie
admin1 admin12 admin1234 administrator1 sysadmin superuser supervisor manager operator support service
root1 toor1 system system1 server server1 database oracle mysql postgres postgresql sql
webmaster web webadmin master1 backup demo demo123 sample example test1 testing123 tester1
georef georef123 georeference georeferencing survey surveyor surveying drone drones dronesurvey
correcthorsebatterystaple correcthorse trustnoone letmeinnow passwordpassword
photogrammetry gnss rtk ppk quarry earthworks stockpile
"""

# keyboard rows, walks and runs that are at least 10 characters long
WALKS = """
1234567890 0987654321 12345678910 123456789012 1234567890123 0123456789 9876543210 01234567890
qwertyuiop poiuytrewq asdfghjkl; lkjhgfdsa zxcvbnm,./ qwertyuiop[] qwertyuiopasdfghjkl
1qaz2wsx3edc 1qaz2wsx3edc4rfv 1qazxsw23edc qazwsxedcrfv qazwsxedcrfvtgb zaq12wsxcde3 zaq1xsw2cde3
1q2w3e4r5t 1q2w3e4r5t6y 1q2w3e4r5t6y7u q1w2e3r4t5 q1w2e3r4t5y6 !qaz@wsx#edc !q@w#e$r%t
abcdefghij abcdefghijk abcdefghijkl abcdefghijklmnop abcdefghijklmnopqrstuvwxyz zyxwvutsrq
qweasdzxc123 qwe123asd456 123qweasdzxc asdfqwerzxcv qwerasdfzxcv qwertyasdfgh asdfghqwerty
1122334455 11223344556677 1212121212 1231231231 123123123123 1234512345 12345678987654321
1111111111 2222222222 3333333333 4444444444 5555555555 6666666666 7777777777 8888888888 9999999999
0000000000 1010101010 1357924680 1470258369 1478963250 2468013579 9999999999 10203040506
aaaaaaaaaa abcabcabcabc abc123abc123 qweqweqweqwe asdasdasdasd zxczxczxc qazqazqaz
passwordpassword password1234567 passwordqwerty qwertypassword iloveyouiloveyou
"""

# (the policy strips digits and symbols around a password before the look-up: these long forms are the
# ones that also match without it, e.g. in other tools reading the list)
SUFFIXES = ["1", "12", "123", "1234", "12345", "123456", "!", "1!", "123!", "01", "69", "007"] + \
    [str(y) for y in range(2018, 2027)]
PREFIXES = ["my", "the", "ilove", "super", "big"]
TOP_FOR_VARIANTS = 120   # the first base words get decorated variants


def build() -> list[str]:
    base = []
    for w in BASE.split():
        w = w.strip().lower()
        if w and w not in base:
            base.append(w)
    words = list(base)
    for w in WALKS.split():
        words.append(w.lower())
    alpha = [w for w in base if w.isalpha()][:TOP_FOR_VARIANTS]
    for w in alpha:
        for suf in SUFFIXES:
            words.append(w + suf)
        for pre in PREFIXES:
            words.append(pre + w)
        words.append(w + w)
        words.append(w.capitalize() + "1")
    seen, out = set(), []
    for w in words:
        w = w.lower()
        if w not in seen:
            seen.add(w)
            out.append(w)
    return out


def main() -> int:
    words = build()
    header = ("# Common passwords refused by the password policy (backend/core/passwords.py): base words and\n"
              "# frequent long forms, lower case, one per line. Generated by scripts/make_common_passwords.py.\n")
    OUT.write_text(header + "\n".join(words) + "\n", encoding="utf-8")
    print(f"{len(words)} passwords -> {OUT}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
